#!/usr/bin/env bash
# Build the sdist and the wheel (from the sdist), install the wheel into two fresh venvs outside
# the checkout (no extras: .ci/smoke_env_only.py; the rl and plots extras:
# .ci/smoke_installed.py) and run the checks from an unrelated folder.
# Usage: .ci/wheel_smoke.sh [PYTHON]   (the fresh venv's interpreter, default python3)
# BUILD_PYTHON (default: the checkout's .venv, made by `make`) needs the `build` package.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
PYTHON="${1:-python3}"
WORK="$(mktemp -d "${TMPDIR:-/tmp}/quadslam-wheel.XXXXXX")"
trap 'rm -rf "$WORK"' EXIT
start=$SECONDS

"${BUILD_PYTHON:-$ROOT/.venv/bin/python}" -m build --outdir "$WORK/dist" "$ROOT" >"$WORK/build.log" 2>&1 \
    || { cat "$WORK/build.log"; exit 1; }
if grep -i "deprecat" "$WORK/build.log"; then
    echo "wheel_smoke: the build printed deprecation warnings" >&2
    exit 1
fi
rm -rf "$ROOT/build" "$ROOT"/*.egg-info

WHEEL="$(ls "$WORK"/dist/*.whl)"
mkdir "$WORK/elsewhere"
cp "$ROOT/.ci/smoke_installed.py" "$ROOT/.ci/smoke_env_only.py" "$WORK/elsewhere/"

# The env-only install: no extras, so no torch, SB3, tensorboard or matplotlib.
"$PYTHON" -m venv "$WORK/venv-env"
"$WORK/venv-env/bin/python" -m pip install --quiet -c "$ROOT/constraints.txt" "$WHEEL"
(cd "$WORK/elsewhere" && env -u PYTHONPATH -u QUADSLAM_CONFIG_DIR OPENBLAS_NUM_THREADS=1 \
    "$WORK/venv-env/bin/python" smoke_env_only.py)

# Everything a user of the RL side installs.
"$PYTHON" -m venv "$WORK/venv"
"$WORK/venv/bin/python" -m pip install --quiet -c "$ROOT/constraints.txt" torch==2.13.0
"$WORK/venv/bin/python" -m pip install --quiet -c "$ROOT/constraints.txt" "$WHEEL[rl,plots]"
cd "$WORK/elsewhere"
env -u PYTHONPATH -u QUADSLAM_CONFIG_DIR MPLBACKEND=Agg OPENBLAS_NUM_THREADS=1 \
    "$WORK/venv/bin/python" smoke_installed.py
echo "wheel_smoke: done in $((SECONDS - start)) s"
