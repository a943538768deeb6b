"""scripts/setup.sh's choice of a torch build (the logic, not the download)."""

import subprocess
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "torch_source.sh"


def choice(override: str, gpu: int, local_cpu: int) -> subprocess.CompletedProcess:
    command = f'source "{SCRIPT}"; torch_source "{override}" {gpu} {local_cpu}'
    return subprocess.run(["bash", "-c", command], capture_output=True, text=True)


@pytest.mark.parametrize(
    ("override", "gpu", "local_cpu", "expected"),
    [
        ("", 0, 1, "local"),  # a CPU wheel pip already has (this machine's)
        ("", 1, 1, "local"),
        ("", 0, 0, "cpu"),  # an ordinary machine without a GPU: PyTorch's CPU index, not PyPI's CUDA build
        ("", 1, 0, "cuda"),  # an NVIDIA GPU: PyPI's CUDA build
        ("cuda", 0, 1, "cuda"),  # ROTO_TORCH overrides either way
        ("cpu", 1, 0, "cpu"),
        ("local", 1, 0, "local"),
    ],
)
def test_setup_picks_the_torch_build_for_the_machine(override, gpu, local_cpu, expected):
    done = choice(override, gpu, local_cpu)
    assert done.returncode == 0 and done.stdout.strip() == expected


def test_a_bad_override_is_one_line():
    done = choice("rocm", 0, 0)
    assert (
        done.returncode == 2
        and done.stderr.strip() == "setup: ROTO_TORCH must be local, cpu or cuda, got 'rocm'"
    )
