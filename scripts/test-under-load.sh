#!/usr/bin/env bash
# The test command with CPU-bound processes beside it (tests/README.md, "Under load"): a test
# that fails here is a defect, in the product or in the test's judgement. FTCAP_LOAD_PROCS
# busy loops (default 2: both cores of the reference machine taken) run for as long as the
# tests do and are ended by PID when they stop, whatever their outcome. Arguments go to
# scripts/test.sh (none: the whole suite; e.g. tests/vcan for one tier).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
burners=()
stop_burners() {
  for pid in "${burners[@]}"; do kill "$pid" 2>/dev/null || true; done
  for pid in "${burners[@]}"; do wait "$pid" 2>/dev/null || true; done
}
trap stop_burners EXIT
for _ in $(seq 1 "${FTCAP_LOAD_PROCS:-2}"); do
  "$PY" -c 'while True: pass' &
  burners+=("$!")
done
echo "test-under-load: ${#burners[@]} busy loops beside the tests (pids ${burners[*]})"
status=0
bash scripts/test.sh "$@" || status=$?
exit "$status"
