"""Wall time of several training runs one after another vs side by side with the cores split.

The same multirun (``--runs`` seeds of one experiment) is run twice through ``roto_trl/train.py``:
  one after another   Hydra's basic launcher: each run has every core (torch and physics threads);
  side by side        ``hydra/launcher=joblib hydra.launcher.n_jobs=<jobs>``: ``jobs`` runs at
                      once, each with cores // jobs threads (``roto_trl.trainers.threads``).
It prints each way's wall time (start to end of the whole multirun, Python start-up included),
the speed-up over one after another, and each way's mean training frames/s per run and mean final
evaluation return (the same seeds and values: the results should agree in kind).

    python benchmarks/parallel_runs.py     # 4 quickstart-sized Find runs, 2 at a time
    python benchmarks/parallel_runs.py --exp bounce_ppo --runs 4 --jobs 2 --frames 200000
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path

from roto_trl.utils.resources import TRAIN_SCRIPT


def run_multirun(sweep_dir: Path, args: argparse.Namespace, launcher: list[str]) -> float:
    """Run the multirun into ``sweep_dir``; its wall time in seconds."""
    command = [
        sys.executable,
        str(TRAIN_SCRIPT),
        "-m",
        f"+exp={args.exp}",
        f"+profile={args.profile}",
        "seed=" + ",".join(str(s) for s in range(args.runs)),
        "progress=false",
        "logger=csv",
        f"hydra.sweep.dir={sweep_dir}",
        *([f"total_frames={args.frames}"] if args.frames else []),
        *launcher,
    ]
    print("$", " ".join(command), flush=True)
    start = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def summaries(sweep_dir: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted(sweep_dir.glob("*/summary.json"))]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--exp", default="find_ppo", help="experiment (conf/exp/)")
    parser.add_argument("--profile", default="quickstart", help="size profile (conf/profile/)")
    parser.add_argument("--runs", type=int, default=4, help="runs (seeds 0, 1, ...)")
    parser.add_argument("--jobs", type=int, default=2, help="runs at once in the side-by-side way")
    parser.add_argument("--frames", type=int, default=None, help="total_frames (default: the profile's)")
    parser.add_argument("--out", type=Path, default=None, help="default runs/benchmarks/parallel/<time>")
    args = parser.parse_args()
    out = args.out or Path("runs") / "benchmarks" / "parallel" / f"{datetime.now():%Y%m%d-%H%M%S}"
    cores = len(os.sched_getaffinity(0))

    ways = [
        ("one after another", 1, cores, []),
        (
            "side by side",
            args.jobs,
            max(1, cores // args.jobs),
            ["hydra/launcher=joblib", f"hydra.launcher.n_jobs={args.jobs}"],
        ),
    ]
    results = []
    for name, jobs, threads, launcher in ways:
        sweep_dir = out / name.replace(" ", "-")
        wall = run_multirun(sweep_dir, args, launcher)
        runs = summaries(sweep_dir)
        fps = sum(r["frames_per_s"] for r in runs) / len(runs)
        final = sum(r["final_eval"]["return_mean"] for r in runs) / len(runs)
        results.append((name, jobs, threads, wall, fps, final))

    print(f"\n{args.runs} x {args.exp} +profile={args.profile} on {cores} cores; run directories in {out}")
    header = ("way", "at once", "threads", "wall s", "speed-up", "frames/s/run", "return")
    print(f"{header[0]:<18}" + "".join(f"{h:>13}" for h in header[1:]))
    base = results[0][3]
    for name, jobs, threads, wall, fps, final in results:
        cells = (jobs, threads, f"{wall:.1f}", f"{base / wall:.2f}", f"{fps:,.0f}", f"{final:.2f}")
        print(f"{name:<18}" + "".join(f"{c:>13}" for c in cells))


if __name__ == "__main__":
    main()
