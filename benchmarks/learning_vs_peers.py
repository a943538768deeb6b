"""Learning per frame: our trainer beside a stock PPO library on the same task, network and values.

One after another, with the same seed, worlds, frame budget and PPO values (the experiment's,
with ``--num-envs`` worlds and any extra ``key=value`` overrides for ours):
  ours     ``roto_trl/train.py +exp=<exp>`` (its own run directory under ``--out``)
  rsl_rl   rsl_rl's PPO (``benchmarks/peers.py``: separate actor and critic MLPs of our sizes)
           on our Gymnasium interface (needs ``pip install -e '.[bench]'``)
At each mark it prints the task's episode metric (bounces, rotations, ...) averaged over the
training episodes that ended in the ``--window`` frames before the mark, and each trainer's
frames/s (training only for ours: its ``fps`` column). Then each trainer's final policy plays
``--eval-episodes`` deterministic episodes (our evaluation seed, one per fresh world) with the
Gaussian's mean and with the applied mean (the mean of the env-clipped action, our default), so
a controller that peaks and falls back shows as it does in our own runs. While rsl_rl trains, a
line every tenth of the budget gives its frames, frames/s, time left, training episodes and its
controller's score on ``--curve-episodes`` (32) deterministic episodes (also in ``rsl_rl_eval.csv``:
rsl_rl's evaluation curve, beside our run's ``eval.csv``).

    python benchmarks/learning_vs_peers.py --exp bounce_ppo --num-envs 256 --frames 1000000
    python benchmarks/learning_vs_peers.py --exp bounce_ppo --marks 300k,1M agent.lr_schedule=kl_adaptive
    python benchmarks/learning_vs_peers.py --ours-run runs/bounce_ppo/<run> --frames 2000000 --marks 1M,2M

``--ours-run`` reads a finished run of ours instead of training one (its experiment, seed and
worlds are taken from its config, so the peer trains on exactly those).
"""

from __future__ import annotations

import argparse
import csv
import math
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path

import roto_trl  # noqa: F401  first, before torch loads: sets how its OpenMP threads wait (roto_trl/__init__.py)

# isort: split
import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from roto_trl.analysis.checkpoint_eval import evaluate_checkpoint, load_run
from roto_trl.analysis.stability import training_at
from roto_trl.analysis.table import parse_frames
from roto_trl.config import checked_config, compose_train
from roto_trl.envs.factory import TASKS
from roto_trl.trainers.builders import eval_seed
from roto_trl.utils.resources import TRAIN_SCRIPT

PROGRESS_LINES = 10  # rsl_rl's progress lines over its budget
FINAL_ACTIONS = ("gaussian_mean", "applied_mean")  # the final policies' deterministic actions


def frames_arg(text: str) -> int:
    """``300k``, ``1M``, ``2.5M`` or a plain number of frames (the results table's parser)."""
    (frames,) = parse_frames(text)
    return frames


def threads_overrides(threads: int | None) -> list[str]:
    """The overrides that give torch and the physics ``threads`` threads (none: the defaults)."""
    return [f"torch_threads={threads}", f"+env.overrides.num_threads={threads}"] if threads else []


def ours(args, overrides: list[str], out: Path) -> tuple[list[tuple[int, float, float]], float]:
    """Train with our trainer (or read ``--ours-run``); its ended episodes (one entry per
    iteration: frames, the mean metric of the episodes that ended then, their count) and mean
    training frames/s."""
    if args.ours_run is not None:
        return ended_episodes(args.ours_run, args.metric)
    run_dir = out / "ours"
    command = [
        sys.executable,
        str(TRAIN_SCRIPT),
        f"+exp={args.exp}",
        f"env.num_envs={args.num_envs}",
        f"total_frames={args.frames}",
        f"seed={args.seed}",
        f"run_dir={run_dir}",
        "logger=csv",
        "progress=false",
        *threads_overrides(args.threads),
        *overrides,
    ]
    print("$", " ".join(command), flush=True)
    done = subprocess.run(command)
    if done.returncode != 0:
        sys.exit(f"learning_vs_peers: our trainer stopped with exit code {done.returncode} (see above)")
    return ended_episodes(run_dir, args.metric)


def ended_episodes(run_dir: Path, metric_name: str) -> tuple[list[tuple[int, float, float]], float]:
    """A run's ended episodes and mean training frames/s, from its ``train.csv``."""
    with (run_dir / "train.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    metric = f"episode/{metric_name}"
    episodes = [
        (int(float(r["frames"])), float(r[metric]), float(r["episodes"]))
        for r in rows
        if r.get(metric) not in (None, "", "nan")
    ]
    fps = [float(r["fps"]) for r in rows]
    return episodes, sum(fps) / len(fps)


def ours_final(args, out: Path) -> dict[str, dict[str, float]]:
    """The physical metrics of our run's final policy (``latest.pt``) with each of
    ``FINAL_ACTIONS``."""
    run_dir = args.ours_run if args.ours_run is not None else out / "ours"
    cfg, state, _ = load_run(run_dir, "latest")
    return {
        a: evaluate_checkpoint(cfg, state, args.eval_episodes, eval_seed(cfg), policy=a)[0]["physical"]
        for a in FINAL_ACTIONS
    }


def peer_config(args) -> DictConfig:
    """The experiment's config as the peer runs it: its worlds, seed and physics threads."""
    overrides = [f"+exp={args.exp}", f"env.num_envs={args.num_envs}", f"seed={args.seed}"]
    return checked_config(compose_train([*overrides, *threads_overrides(args.threads)[1:]]))


def rsl_rl(
    args, cfg: DictConfig, out: Path, headline: str
) -> tuple[list[tuple[int, float, float]], float, dict[str, dict]]:
    """Train rsl_rl's PPO for the same frames; its ended episodes, training frames/s and the
    final policy's physical metrics per deterministic action. Every tenth of the budget its
    controller plays ``--curve-episodes`` deterministic episodes with each action, as our
    training evaluations do: printed, and written to ``<out>/rsl_rl_eval.csv``."""
    from peers import rsl_rl_evaluate, rsl_rl_runner  # benchmarks/peers.py

    if args.threads:
        torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    runner, env = rsl_rl_runner(cfg)
    iterations = -(-args.frames // (int(cfg.agent.rollout_len) * args.num_envs))
    budget = iterations * env.num_envs * int(cfg.agent.rollout_len)
    chunk = -(-iterations // PROGRESS_LINES)
    train_s, start = 0.0, time.perf_counter()
    with (out / "rsl_rl_eval.csv").open("w", newline="") as handle:
        curve = csv.writer(handle)
        curve.writerow(["frames", *(f"{headline}_{a}" for a in FINAL_ACTIONS)])
        for done in range(0, iterations, chunk):
            t0 = time.perf_counter()
            runner.learn(min(chunk, iterations - done))
            train_s += time.perf_counter() - t0
            recent = [v for end, v in env.episodes if end > env.frames - args.window]
            metric = f"{sum(recent) / len(recent):.2f}" if recent else "-"
            scores = [
                rsl_rl_evaluate(cfg, runner, args.curve_episodes, eval_seed(cfg), a)[headline]
                for a in FINAL_ACTIONS
            ]
            curve.writerow([env.frames, *scores])
            handle.flush()
            left = (time.perf_counter() - start) / env.frames * max(0, budget - env.frames)
            print(
                f"rsl_rl: {env.frames:,} frames, {env.frames / train_s:,.0f} frames/s, about "
                f"{left / 60:.0f} min left; training episodes' {args.metric}: {metric}; "
                f"{headline} of {args.curve_episodes} deterministic episodes (Gaussian's / applied mean): "
                f"{scores[0]:.2f} / {scores[1]:.2f}",
                flush=True,
            )
    env.envs.close()
    finals = {a: rsl_rl_evaluate(cfg, runner, args.eval_episodes, eval_seed(cfg), a) for a in FINAL_ACTIONS}
    return [(end, value, 1.0) for end, value in env.episodes], env.frames / train_s, finals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--exp", default="bounce_ppo", help="experiment (conf/exp/)")
    parser.add_argument("--num-envs", type=int, default=256, help="training worlds")
    parser.add_argument("--frames", type=frames_arg, default=1_000_000, help="frame budget of each")
    parser.add_argument("--marks", default="300k,1M", help="frame counts to compare at")
    parser.add_argument("--window", type=frames_arg, default=49_152, help="episodes ending this close")
    parser.add_argument("--metric", default="bounces", help="episode metric (bounces, rotations, ...)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None, help="default runs/benchmarks/learning/<time>")
    parser.add_argument("--threads", type=int, default=None, help="torch and physics threads of each")
    parser.add_argument("--ours-run", type=Path, default=None, help="a finished run of ours to compare")
    parser.add_argument("--eval-episodes", type=int, default=100, help="episodes of each final policy")
    parser.add_argument("--curve-episodes", type=int, default=32, help="rsl_rl's evaluations while it trains")
    args, overrides = parser.parse_known_args()
    if args.ours_run is not None:
        if not (args.ours_run / "train.csv").is_file():
            parser.error(f"--ours-run {args.ours_run} has no train.csv; give a run directory of train.py")
        if overrides:
            parser.error("--ours-run reads a finished run: its overrides are in its config.yaml, give none")
        run_cfg = OmegaConf.load(args.ours_run / "config.yaml")
        args.exp, args.seed, args.num_envs = run_cfg.exp_name, int(run_cfg.seed), int(run_cfg.env.num_envs)
    bad = [a for a in overrides if "=" not in a or a.startswith("-")]
    if bad:
        parser.error(f"unrecognized arguments: {' '.join(bad)} (extra overrides are key=value)")
    for name in ("eval_episodes", "curve_episodes"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    marks = parse_frames(args.marks)
    if max(marks) > args.frames:
        parser.error(f"--marks {args.marks} go past --frames {args.frames:,}")
    out = args.out or Path("runs/benchmarks/learning") / f"{datetime.now():%Y%m%d-%H%M%S}"
    out.mkdir(parents=True, exist_ok=True)

    cfg = peer_config(args)
    headline = TASKS[cfg.env.task].HEADLINE_METRIC
    results = {"ours": ours(args, overrides, out)}
    finals = {"ours": ours_final(args, out)}
    try:
        *results["rsl_rl"], finals["rsl_rl"] = rsl_rl(args, cfg, out, headline)
    except ImportError:
        print("rsl_rl is not installed (pip install -e '.[bench]'): ours alone", flush=True)

    print(f"\n{args.exp}, {args.num_envs} worlds, seed {args.seed}, {' '.join(overrides) or 'its values'}")
    print(f"{args.metric} per training episode ended in the {args.window:,} frames before each mark")
    header = f"{'trainer':<8}" + "".join(f"{m:>12,}" for m in marks) + f"{'frames/s':>10}"
    print(header + "\n" + "-" * len(header))
    for name, (episodes, fps) in results.items():
        ends, values, weights = np.asarray(episodes, dtype=float).reshape(-1, 3).T  # none ended: empty
        cells = training_at(ends, values, weights, marks, args.window, until=args.frames)
        text = "".join(f"{'-':>12}" if math.isnan(c) else f"{c:>12.2f}" for c in cells)
        print(f"{name:<8}{text}{fps:>10,.0f}")
    print(f"\nfinal policy, {args.eval_episodes} deterministic episodes: {headline}")
    print(f"{'trainer':<8}" + "".join(f"{a:>16}" for a in FINAL_ACTIONS))
    for name, by_action in finals.items():
        print(f"{name:<8}" + "".join(f"{by_action[a][headline]:>16.2f}" for a in FINAL_ACTIONS))
    print(f"runs: {out}")


if __name__ == "__main__":
    main()
