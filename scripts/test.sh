#!/usr/bin/env bash
# The project's test command (README): unit, contract, closed-loop, end-to-end and vcan tests.
# As root (a fresh machine, CI) it first prepares the SocketCAN VM the vcan tests boot
# (tests/vcan/setup.sh: Debian packages and a kernel, cached; a no-op once done); without
# root the vcan tests say why they skip.
#
# Two runs (tests/README.md): the in-process tiers (unit, contract, closed_loop) spread over
# the cores by pytest-xdist, then the tiers that start processes or a VM (e2e, vcan, docker)
# one test at a time, since their claims are about timing on this machine, with the tests
# marked ``alone`` (memory bounds of their own process). With arguments, one plain pytest
# run of what they select.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "$(id -u)" = 0 ] && [ -f tests/vcan/setup.sh ] && command -v apt-get >/dev/null; then
  bash tests/vcan/setup.sh
fi
PY=${PYTHON:-python}
[ -x .venv/bin/python ] && PY=.venv/bin/python
if [ "$#" -gt 0 ]; then
  exec "$PY" -m pytest -p no:cacheprovider --durations=30 "$@"
fi
IN_PROCESS="unit or contract or closed_loop"
status=0
"$PY" -m pytest -p no:cacheprovider -n "${FTCAP_TEST_WORKERS:-auto}" --durations=10 \
  -m "($IN_PROCESS) and not alone" || status=$?
"$PY" -m pytest -p no:cacheprovider --durations=30 -m "not ($IN_PROCESS) or alone" || status=$?
exit "$status"
