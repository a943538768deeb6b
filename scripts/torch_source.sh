# Which build of torch scripts/setup.sh installs (sourced by it, and by the tests of this logic).
#
#   torch_source OVERRIDE HAS_NVIDIA_GPU LOCAL_CPU_WHEEL   ->  prints local | cpu | cuda
#
# OVERRIDE is $ROTO_TORCH (empty: choose): local takes whatever pip's own configuration offers for
# torch==2.13.0 (here: the CPU wheel on disk), cpu PyTorch's CPU wheel index, cuda PyPI's CUDA
# build. Without an override: a local CPU wheel when pip has one, else the CUDA build where an
# NVIDIA GPU is present, else the CPU index (PyPI's default for torch is the multi-GB CUDA build).
torch_source() {
  case "$1" in
    local | cpu | cuda) echo "$1"; return 0 ;;
    "") ;;
    *) echo "setup: ROTO_TORCH must be local, cpu or cuda, got '$1'" >&2; return 2 ;;
  esac
  if [ "$3" = 1 ]; then
    echo local
  elif [ "$2" = 1 ]; then
    echo cuda
  else
    echo cpu
  fi
}
