"""Env steps/s of full PPO training beside sim-only stepping of the same env, in the same run.

Training is ``roto_trl/train.py``'s iteration (collector with the policy acting, advantage
estimate, PPO update) with the paper's Baoding PPO(prop-tactile) values (R 32, mb 4, le 8) at
1024 worlds; sim-only steps the same env with random actions through ``step_and_maybe_reset``.
Time per iteration is split into collection (of which acting: the policy's forward passes),
advantages and update. Goal: training >= 0.5 of sim-only. ``--objectives`` adds one row per
self-supervised objective (same PPO values, the objective's defaults from ``conf/ssl/``).

    python benchmarks/train_throughput.py
    python benchmarks/train_throughput.py --objectives ppo tr fr fd:2 fd:4 fd:10 tfd:2
    python benchmarks/train_throughput.py --exp find_ppo --num-envs 256 --iterations 2
"""

from __future__ import annotations

import argparse
import logging
import time

import torch
from hydra import compose, initialize_config_dir

from roto_trl.trainers.builders import (
    agent_for_env,
    make_advantage,
    make_aux_update,
    make_collector,
    make_optimizer,
    make_ppo_loss,
    make_rollout_buffer,
    make_train_env,
)
from roto_trl.trainers.ppo import ppo_update, store_rollout
from roto_trl.utils.resources import resource_dir


def sim_only(env, steps: int) -> float:
    """Control steps/s of ``env`` under random actions (episodes end and reset as in training)."""
    n, n_actions = env.batch_size[0], env.base_env.n_actions
    td = env.reset()
    start = time.perf_counter()
    for _ in range(steps):
        td.set("action", torch.rand(n, n_actions) * 2 - 1)
        _, td = env.step_and_maybe_reset(td)
    return steps * n / (time.perf_counter() - start)


@torch.no_grad()
def acting_seconds(agent, batch) -> float:
    """Time of the policy's forward passes in one rollout: R calls on the N worlds' observations."""
    obs = batch[:, 0].select(*agent.obs_keys).clone()
    start = time.perf_counter()
    for _ in range(batch.shape[1]):
        agent.policy(obs.clone())
    return time.perf_counter() - start


def measure(cfg, iterations: int) -> tuple[float, dict[str, float]]:
    """Training steps/s over ``iterations`` (after one warm-up) and seconds per phase."""
    torch.manual_seed(0)
    env = make_train_env(cfg)
    agent = agent_for_env(cfg, env)
    loss_fn = make_ppo_loss(cfg, agent)
    advantage = make_advantage(cfg)
    optimizer = make_optimizer(cfg, agent)
    aux = make_aux_update(cfg, agent, env)
    params = list(agent.parameters())
    collector = make_collector(cfg, env, agent)
    buffer = make_rollout_buffer(cfg)
    phases = {"collect": 0.0, "acting": 0.0, "advantages": 0.0, "update": 0.0}
    frames = 0
    t_collect = time.perf_counter()
    for i, batch in enumerate(collector):
        collect = time.perf_counter() - t_collect
        t0 = time.perf_counter()
        store_rollout(batch, agent, advantage, buffer, aux)
        t1 = time.perf_counter()
        ppo_update(cfg, buffer, agent, loss_fn, optimizer, params, aux)
        t2 = time.perf_counter()
        if i > 0:  # iteration 0 warms up
            frames += batch.numel()
            phases["collect"] += collect
            phases["acting"] += acting_seconds(agent, batch)
            phases["advantages"] += t1 - t0
            phases["update"] += t2 - t1
        if i == iterations:
            break
        t_collect = time.perf_counter()
    collector.shutdown()
    env.close()
    total = phases["collect"] + phases["advantages"] + phases["update"]
    return frames / total, {k: v / iterations for k, v in phases.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("--exp", default="baoding_ppo")
    parser.add_argument("--num-envs", type=int, default=1024)
    parser.add_argument("--iterations", type=int, default=3, help="timed iterations (after one warm-up)")
    parser.add_argument(
        "--objectives",
        nargs="+",
        default=["ppo"],
        help="rows: ppo (alone), tr, fr, fd:<n>, tfd:<n>, e.g. --objectives ppo tr fd:2 fd:4 fd:10",
    )
    args = parser.parse_args()
    logging.getLogger("torchrl").setLevel(logging.WARNING)
    base = [f"+exp={args.exp}", f"env.num_envs={args.num_envs}", "logger.backend=none"]
    with initialize_config_dir(str(resource_dir("conf")), version_base="1.3"):
        cfg = compose("train", overrides=base)
        sim_env = make_train_env(cfg)
        sim = sim_only(sim_env, int(cfg.agent.rollout_len) * 2)
        sim_env.close()
        a = cfg.agent
        print(
            f"{args.exp}: {args.num_envs} worlds, R {a.rollout_len}, mb {a.minibatches}, le {a.epochs}, "
            f"torch threads {torch.get_num_threads()}, {args.iterations} timed iterations"
        )
        print(f"sim only: {sim:,.0f} steps/s (random actions, same env)")
        columns = ("steps/s", "/ sim", "collect", "acting", "adv", "update")
        widths = (8, 6, 8, 8, 6, 8)
        header = " ".join(f"{c:>{w}}" for c, w in zip(columns, widths, strict=True))
        print(f"{'objective':<10} {header}   (share of an iteration; acting is part of collect)")
        for spec in args.objectives:
            name, _, n = spec.partition(":")
            extra = [] if name == "ppo" else [f"ssl={name}", *([f"ssl.seq_len={n}"] if n else [])]
            row_cfg = compose("train", overrides=[*base, *extra])
            fps, per = measure(row_cfg, args.iterations)
            total = per["collect"] + per["advantages"] + per["update"]
            share = {k: v / total for k, v in per.items()}
            print(
                f"{spec:<10} {fps:>8,.0f} {fps / sim:>6.2f} {share['collect']:>8.1%} "
                f"{share['acting']:>8.1%} {share['advantages']:>6.1%} {share['update']:>8.1%}",
                flush=True,
            )


if __name__ == "__main__":
    main()
