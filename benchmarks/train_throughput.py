"""Env steps/s of full PPO training beside sim-only stepping of the same env, in the same run.

Training is ``roto_trl/train.py``'s iteration (collector with the policy acting, advantage
estimate, PPO update) with the paper's Baoding PPO(prop-tactile) values (R 32, mb 4, le 8) at
1024 worlds; sim-only steps the same env with random actions through ``step_and_maybe_reset``.
Time per iteration is split into collection (of which acting: the policy's forward passes),
advantages and update. Goal: training >= 0.5 of sim-only.

    python benchmarks/train_throughput.py
    python benchmarks/train_throughput.py --exp find_ppo --num-envs 256 --iterations 2
"""

from __future__ import annotations

import argparse
import time

import torch
from hydra import compose, initialize_config_dir

from roto_trl.builders import (
    agent_for_env,
    make_advantage,
    make_collector,
    make_optimizer,
    make_ppo_loss,
    make_rollout_buffer,
    make_train_env,
)
from roto_trl.resources import resource_dir
from roto_trl.train import estimate_advantages, ppo_update


class TimedPolicy(torch.nn.Module):
    """The policy, with the time spent in its forward passes added up (the collector's acting)."""

    def __init__(self, policy) -> None:
        super().__init__()
        self.policy = policy
        self.seconds = 0.0

    def forward(self, td):
        start = time.perf_counter()
        out = self.policy(td)
        self.seconds += time.perf_counter() - start
        return out


def sim_only(env, steps: int) -> float:
    """Control steps/s of ``env`` under random actions (episodes end and reset as in training)."""
    n, n_actions = env.batch_size[0], env.base_env.n_actions
    td = env.reset()
    start = time.perf_counter()
    for _ in range(steps):
        td.set("action", torch.rand(n, n_actions) * 2 - 1)
        _, td = env.step_and_maybe_reset(td)
    return steps * n / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("--exp", default="baoding_ppo")
    parser.add_argument("--num-envs", type=int, default=1024)
    parser.add_argument("--iterations", type=int, default=3, help="timed iterations (after one warm-up)")
    args = parser.parse_args()
    overrides = [f"+exp={args.exp}", f"env.num_envs={args.num_envs}", "logger.backend=none"]
    with initialize_config_dir(str(resource_dir("conf")), version_base="1.3"):
        cfg = compose("train", overrides=overrides)
    torch.manual_seed(0)
    torch.set_num_threads(torch.get_num_threads())

    env = make_train_env(cfg)
    agent = agent_for_env(cfg, env)
    loss_fn = make_ppo_loss(cfg, agent)
    advantage = make_advantage(cfg)
    optimizer = make_optimizer(cfg, agent)
    params = list(agent.parameters())
    timed = TimedPolicy(agent.policy)
    collector = make_collector(cfg, env, agent)
    collector.policy = timed  # same module, timed
    buffer = make_rollout_buffer(cfg)

    phases = {"collect": 0.0, "acting": 0.0, "advantages": 0.0, "update": 0.0}
    frames = 0
    t_collect = time.perf_counter()
    for i, batch in enumerate(collector):
        collect = time.perf_counter() - t_collect
        t0 = time.perf_counter()
        estimate_advantages(batch, agent, advantage)
        buffer.empty()
        buffer.extend(batch.reshape(-1))
        t1 = time.perf_counter()
        ppo_update(cfg, buffer, agent, loss_fn, optimizer, params)
        t2 = time.perf_counter()
        if i > 0:  # iteration 0 warms up
            frames += batch.numel()
            phases["collect"] += collect
            phases["acting"] += timed.seconds
            phases["advantages"] += t1 - t0
            phases["update"] += t2 - t1
        timed.seconds = 0.0
        if i == args.iterations:
            break
        t_collect = time.perf_counter()
    collector.shutdown()
    sim_env = make_train_env(cfg)
    sim = sim_only(sim_env, int(cfg.agent.rollout_len) * 2)
    sim_env.close()

    total = phases["collect"] + phases["advantages"] + phases["update"]
    train_fps = frames / total
    a = cfg.agent
    print(
        f"{args.exp}: {args.num_envs} worlds, R {a.rollout_len}, mb {a.minibatches}, le {a.epochs}, "
        f"torch threads {torch.get_num_threads()}, {frames:,} timed frames"
    )
    print(f"{'':<24} {'steps/s':>10}")
    print(f"{'sim only':<24} {sim:>10,.0f}")
    print(f"{'PPO training':<24} {train_fps:>10,.0f}   ratio {train_fps / sim:.2f}")
    print("where a training iteration's time goes:")
    for name in ("collect", "acting", "advantages", "update"):
        label = "  acting (in collect)" if name == "acting" else name
        share, per_iteration = phases[name] / total, phases[name] / args.iterations
        print(f"  {label:<22} {share:>6.1%}  ({per_iteration:.2f} s/iteration)")


if __name__ == "__main__":
    main()
