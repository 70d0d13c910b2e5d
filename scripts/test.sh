#!/usr/bin/env bash
# The project's test command (README): unit, contract, closed-loop, end-to-end and vcan tests.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python}
[ -x .venv/bin/python ] && PY=.venv/bin/python
exec "$PY" -m pytest -p no:cacheprovider "$@"
