#!/usr/bin/env bash
# Create the virtual environment at .venv (repo root) and install RoTO-TRL with its dev tools.
# Idempotent: it re-installs only when pyproject.toml changed since the last successful run.
#
# torch is installed first, pinned to 2.13.0, from the source scripts/torch_source.sh chooses:
# a CPU wheel pip already has (its find-links or index), PyTorch's CPU wheel index on a machine
# without an NVIDIA GPU (about 200 MB), or PyPI's CUDA build where there is one (several GB).
# ROTO_TORCH=local|cpu|cuda overrides the choice.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/torch_source.sh

TORCH="torch==2.13.0"
CPU_INDEX="https://download.pytorch.org/whl/cpu"
python_bin="${PYTHON:-python3.11}"
command -v "$python_bin" >/dev/null 2>&1 || python_bin=python3
stamp=.venv/.roto-trl-installed
want="$(sha256sum pyproject.toml | cut -d' ' -f1)"

if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && [ -x .venv/bin/python ]; then
  exit 0
fi
echo "setup: creating .venv and installing roto-trl (a minute or two; more where torch is downloaded)"
[ -x .venv/bin/python ] || "$python_bin" -m venv .venv
pip=(.venv/bin/pip --disable-pip-version-check)

has_gpu=0
if [ -e /proc/driver/nvidia/version ] || { command -v nvidia-smi >/dev/null && nvidia-smi -L >/dev/null 2>&1; }; then
  has_gpu=1
fi
local_cpu=0
report="$(mktemp)"
if "${pip[@]}" install --quiet --dry-run --no-deps --ignore-installed --report "$report" "$TORCH" >/dev/null 2>&1 \
  && grep -q '+cpu' "$report"; then
  local_cpu=1
fi
rm -f "$report"
source="$(torch_source "${ROTO_TORCH:-}" "$has_gpu" "$local_cpu")"
echo "setup: torch 2.13.0 from: $source (NVIDIA GPU: $has_gpu, a CPU wheel pip already has: $local_cpu)"
case "$source" in
  cpu) "${pip[@]}" install --quiet "$TORCH" --index-url "$CPU_INDEX" ;;
  *) "${pip[@]}" install --quiet "$TORCH" ;;
esac
"${pip[@]}" install --quiet -e ".[dev]"
echo "$want" > "$stamp"
echo "setup: done ($(.venv/bin/python -c 'import torch, torchrl, tensordict, mujoco; print(f"torch {torch.__version__}, torchrl {torchrl.__version__}, tensordict {tensordict.__version__}, mujoco {mujoco.__version__}")'))"
