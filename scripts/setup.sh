#!/usr/bin/env bash
# Create the virtual environment at .venv (repo root) and install RoTO-TRL with its dev tools.
# Idempotent: it re-installs only when pyproject.toml changed since the last successful run.
set -euo pipefail
cd "$(dirname "$0")/.."

python_bin="${PYTHON:-python3.11}"
command -v "$python_bin" >/dev/null 2>&1 || python_bin=python3
stamp=.venv/.roto-trl-installed
want="$(sha256sum pyproject.toml | cut -d' ' -f1)"

if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && [ -x .venv/bin/python ]; then
  exit 0
fi
echo "setup: creating .venv and installing roto-trl (first run takes a minute or two)"
[ -x .venv/bin/python ] || "$python_bin" -m venv .venv
# torch first and pinned: 2.13.0 is the CPU build this machine carries; any other version would
# pull PyPI's CUDA build (several GB). The package's own range (>=2.13,<2.16) accepts it.
.venv/bin/pip install --quiet --disable-pip-version-check "torch==2.13.0"
.venv/bin/pip install --quiet --disable-pip-version-check -e ".[dev]"
echo "$want" > "$stamp"
echo "setup: done ($(.venv/bin/python -c 'import torch, torchrl, tensordict, mujoco; print(f"torch {torch.__version__}, torchrl {torchrl.__version__}, tensordict {tensordict.__version__}, mujoco {mujoco.__version__}")'))"
