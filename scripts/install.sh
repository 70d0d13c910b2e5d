#!/usr/bin/env bash
# The project's install, the same for a newcomer (README's first command) and for CI:
# a virtual environment in .venv with ftcap-hil, its test tools, and exactly the dependency
# versions docker/requirements.lock pins (the Docker image installs the same pins).
set -euo pipefail
cd "$(dirname "$0")/.."
export PIP_DISABLE_PIP_VERSION_CHECK=1
[ -x .venv/bin/python ] || python3 -m venv .venv
.venv/bin/pip install -q --upgrade pip
.venv/bin/pip install -q -c docker/requirements.lock -e '.[test]'
# What this venv was installed from (the lock's digest): tests/docker judges the installed
# versions against the lock only in an environment that says it came from the lock.
sha256sum docker/requirements.lock > .venv/ftcap-installed-from.lock.sha256
# MAVProxy for the ground-station interop test. Its hard dependencies include opencv and vtk
# (hundreds of MB, for map/GUI modules we never load): installed without them, plus the two
# small packages its param/cmdlong/misc modules need.
.venv/bin/pip install -q --no-deps 'MAVProxy==1.8.75'
.venv/bin/pip install -q -c docker/requirements.lock pyserial defusedxml
echo "installed: $(.venv/bin/ftcap-hil --version 2>/dev/null || echo ftcap-hil) in $(pwd)/.venv"
