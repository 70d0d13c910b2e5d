#!/usr/bin/env bash
# The project's test command (README): unit, contract, closed-loop, end-to-end and vcan tests.
# As root (a fresh machine, CI) it first prepares the SocketCAN VM the vcan tests boot
# (tests/vcan/setup.sh: Debian packages and a kernel, cached; a no-op once done); without
# root the vcan tests say why they skip.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "$(id -u)" = 0 ] && [ -f tests/vcan/setup.sh ] && command -v apt-get >/dev/null; then
  bash tests/vcan/setup.sh
fi
PY=${PYTHON:-python}
[ -x .venv/bin/python ] && PY=.venv/bin/python
exec "$PY" -m pytest -p no:cacheprovider --durations=30 "$@"
