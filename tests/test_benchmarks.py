"""The training benchmark keeps running as the trainer changes (its numbers are not checked here)."""

import re
import subprocess
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def test_train_throughput_measures_an_ssl_experiment():
    command = [
        sys.executable,
        str(BENCHMARKS / "train_throughput.py"),
        *("--exps", "bounce_fd", "--num-envs", "16", "--iterations", "1", "--no-peers"),
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    row = next(line for line in done.stdout.splitlines() if line.startswith("bounce_fd"))
    ours, sim, update, limit, ratio = row.split()[2:7]
    assert all(float(v.replace(",", "")) > 0 for v in (ours, sim, update, limit))
    assert re.fullmatch(r"\d+\.\d\d", ratio)
