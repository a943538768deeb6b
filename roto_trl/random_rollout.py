"""Random-policy rollout of each task: control steps/s and episode metrics, a quick check of the
simulator.

Uniform random actions in [-1, 1] through the full observation pipeline (``make_env``), with
episodes ending and partially resetting as in training. Writes ``summary.json`` under ``--out``
and prints where it is.

    python -m roto_trl.random_rollout                     # every task, 256 envs, 600 steps
    python -m roto_trl.random_rollout --tasks bounce --num-envs 1024 --steps 300
"""

from __future__ import annotations

import argparse
import json
import time
from datetime import datetime
from pathlib import Path

import roto_trl  # noqa: F401  first, before torch loads: sets how its OpenMP threads wait (roto_trl/__init__.py)

# isort: split
import torch

from roto_trl import TASKS, make_env


def rollout_task(task: str, num_envs: int, steps: int, seed: int) -> dict:
    """Run ``steps`` control steps of random actions; returns throughput and episode statistics."""
    env = make_env(task, num_envs, seed=seed)
    base = env.base_env
    metric = base.METRICS[0]
    gen = torch.Generator().manual_seed(seed)
    ep_return = torch.zeros(num_envs)
    ep_length = torch.zeros(num_envs, dtype=torch.long)
    finished = {"return": [], "length": [], metric: [], "terminated": []}
    td = env.reset()
    start = time.perf_counter()
    for step in range(1, steps + 1):
        td.set("action", torch.rand(num_envs, base.n_actions, generator=gen) * 2 - 1)
        td, td_next = env.step_and_maybe_reset(td)
        out = td["next"]
        ep_return += out["reward"].squeeze(-1)
        ep_length += 1
        done = out["done"].squeeze(-1)
        if bool(done.any()):
            finished["return"] += ep_return[done].tolist()
            finished["length"] += ep_length[done].tolist()
            finished[metric] += out[metric].squeeze(-1)[done].tolist()
            finished["terminated"] += out["terminated"].squeeze(-1)[done].tolist()
            ep_return[done] = 0.0
            ep_length[done] = 0
        td = td_next
        if step % max(1, steps // 5) == 0:
            rate = step * num_envs / (time.perf_counter() - start)
            print(
                f"  {task}: step {step}/{steps}, {rate:,.0f} steps/s, {len(finished['return'])} episodes done"
            )
    elapsed = time.perf_counter() - start
    env.close()

    def mean(values):
        return sum(values) / len(values) if values else None

    return {
        "task": task,
        "num_envs": num_envs,
        "control_steps": steps * num_envs,
        "seconds": round(elapsed, 3),
        "steps_per_s": round(steps * num_envs / elapsed, 1),
        "episodes": len(finished["return"]),
        "mean_return": mean(finished["return"]),
        "mean_length": mean(finished["length"]),
        f"mean_{metric}": mean(finished[metric]),
        "terminated_fraction": mean([float(t) for t in finished["terminated"]]),
    }


def main(argv: list[str] | None = None) -> Path:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("--tasks", nargs="+", default=sorted(TASKS), choices=sorted(TASKS))
    parser.add_argument("--num-envs", type=int, default=256)
    parser.add_argument("--steps", type=int, default=600, help="control steps per task (600 = 10 s)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("runs"), help="parent folder of the run folder")
    args = parser.parse_args(argv)
    if args.num_envs < 1 or args.steps < 1:
        parser.error("--num-envs and --steps must be positive")

    run_dir = args.out / f"random_rollout-{datetime.now():%Y%m%d-%H%M%S}"
    run_dir.mkdir(parents=True, exist_ok=True)
    results = []
    for task in args.tasks:
        print(f"{task}: {args.num_envs} envs x {args.steps} steps of random actions")
        results.append(rollout_task(task, args.num_envs, args.steps, args.seed))
        r = results[-1]
        metric = next(k for k in r if k.startswith("mean_") and k not in ("mean_return", "mean_length"))
        value = "n/a" if r[metric] is None else f"{r[metric]:.2f}"
        ret = "n/a" if r["mean_return"] is None else f"{r['mean_return']:.2f}"
        print(
            f"{task}: {r['steps_per_s']:,.0f} control steps/s; {r['episodes']} episodes ended, "
            f"mean return {ret}, {metric[5:]} per episode {value}"
        )
    summary = run_dir / "summary.json"
    summary.write_text(
        json.dumps({"args": vars(args) | {"out": str(args.out)}, "results": results}, indent=2)
    )
    print(f"results: {summary.resolve()}")
    return summary


if __name__ == "__main__":
    main()
