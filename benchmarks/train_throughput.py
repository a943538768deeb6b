"""Training frames/s beside its two limits and the peers, on the same task, worlds, network and values.

For each experiment and world count it measures, in one process and round by round (each timed
iteration of ours is a round; sim, act and update are timed right after it, for the same frames,
so the VM's drift between minutes hits ours and its limits alike):
  ours     ``roto_trl/train.py``'s iteration (collector with the policy acting, advantages, PPO
           update, and the SSL step where the experiment has one), evaluation excluded;
  sim      a second env of the same config stepped as many steps with random actions through
           ``step_and_maybe_reset`` (episodes end and reset as in training);
  update   the bare update: ``epochs x minibatches`` steps of forward + backward + optimiser of
           the same agent and losses (``ClipPPOLoss``, the SSL loss) on one minibatch of the
           round's rollout, so no sampling, advantages or logging (the agent's weights are put
           back after it);
  act      the policy acting alone: its forward pass and sample on each of the round's rollout
           steps (``N`` worlds at a time, the collector's inputs), no env;
  skrl, rsl_rl  their PPO (same 1024-512-256 ELU network, R, mb, le, lr, clip values; rsl_rl's
           MLP without LayerNorm, ``rsl_rl_ln`` the same with our LayerNorms) on our Gymnasium
           interface, when installed (``pip install -e .[bench]``); they have no
           self-supervised objective, so for an SSL experiment (``bounce_fd``) they run its PPO
           values without it and ours / peer understates ours.
It prints frames/s, each phase's share of our iteration, ours / serial limit where the serial
limit is 1 / (1/sim + 1/update) (collection and update run one after the other on the same
cores), ours / the same limit with acting added (1 / (1/sim + 1/update + 1/act): every PPO
acts on every step, which the serial limit does not count, so the gap left here is our loop's
own bookkeeping and the small operations' slowdown between phases, which the parts timed back
to back do not pay), ``lim range`` (the lowest and highest ours / serial limit of the single
rounds; the other figures are over all rounds together), ours / best peer and the precision of
our matrix products (``agent.precision`` resolved for this machine: ``+profile=cpu`` takes
``auto`` on Bounce and Baoding, bfloat16 on a CPU with AMX or AVX512-BF16; the peers run
float32). Goals: >= 0.9 of the serial limit, >= 1.0 of the best peer.
``--compile`` runs ours and the bare update with ``agent.compile=true``; ``--profile cpu`` measures
the CPU recipe (``+profile=cpu``: separate critic, KL-adaptive rate, 8 minibatches; the peers
take its minibatch count too) at each ``--num-envs``; ``--set KEY=VALUE ...`` adds Hydra overrides
(the peers follow ``agent.critic_encoder_sizes``, see ``peers.py``).

    python benchmarks/train_throughput.py          # bounce_ppo and bounce_fd at 256 and 1024 worlds
    python benchmarks/train_throughput.py --exps bounce_ppo --num-envs 256 --iterations 2
    python benchmarks/train_throughput.py --exps baoding_ppo --num-envs 1024 --no-peers
    python benchmarks/train_throughput.py --profile cpu --iterations 2   # the recipe a CPU user runs
    python benchmarks/train_throughput.py --exps bounce_ppo --profile cpu \\
        --set 'agent.critic_encoder_sizes=[256,128]'      # the recipe with a smaller critic
"""

from __future__ import annotations

import os

import roto_trl  # noqa: F401  first, before torch loads: sets how its OpenMP threads wait (roto_trl/__init__.py)

# isort: split
import argparse
import contextlib
import copy
import importlib.util
import io
import logging
import sys
import time

import torch
from peers import PEERS  # benchmarks/peers.py (skrl and rsl_rl are imported only when they run)
from torchrl.envs.utils import ExplorationType, set_exploration_type

from roto_trl.config import checked_config, compose_train, settle_for_machine
from roto_trl.trainers.builders import (
    agent_for_env,
    make_collector,
    make_train_env,
    make_update,
)
from roto_trl.utils.resources import resource_dir

PEER_WIDTH = {p: max(7, len(p)) for p in PEERS}  # each peer's column width


def sim_seconds(env, td, steps: int):
    """Seconds of ``steps`` control steps of ``env`` under random actions, going on from ``td``
    (episodes end and reset as in training), and the tensordict to go on from next time."""
    n, n_actions = env.batch_size[0], env.base_env.n_actions
    start = time.perf_counter()
    for _ in range(steps):
        td.set("action", torch.rand(n, n_actions) * 2 - 1)
        _, td = env.step_and_maybe_reset(td)
    return time.perf_counter() - start, td


@torch.no_grad()
def acting_only(agent, batch) -> float:
    """Seconds of the policy acting on every step of ``batch`` ``[N, R]``: its forward pass and
    sample on each step's observations of the ``N`` worlds, as the collector calls it."""
    steps = [batch[:, t].select(*agent.obs_keys).clone() for t in range(batch.shape[1])]
    with set_exploration_type(ExplorationType.RANDOM):
        start = time.perf_counter()
        for td in steps:
            agent.policy(td)
    return time.perf_counter() - start


def bare_update(update, minibatch, aux_batch) -> float:
    """Seconds of one iteration's updates (``epochs x minibatches`` steps) on fixed minibatches:
    the paper's Eq. 2 as training does it (``PPOUpdate.step``: one backward of L_PPO + c_aux
    L_aux, then the PPO optimiser and, with an SSL objective, the auxiliary one and the target
    EMA). The update's state (weights, optimisers) is put back after it (untimed), so that what
    our next iteration collects does not depend on these steps on one minibatch."""
    saved = copy.deepcopy(update.state_dict())
    start = time.perf_counter()
    for _ in range(update.epochs * update.minibatches):
        data = None if aux_batch is None else aux_batch.clone(False)
        update.step(minibatch.clone(False), data)
    seconds = time.perf_counter() - start
    update.load_state_dict(saved)
    return seconds


def measure(cfg, iterations: int) -> list[dict[str, float]]:
    """One round per timed iteration (after one warm-up round): the seconds of our iteration's
    phases, then, right after it and on its rollout, of the limits' parts for the same frames:
    a second env stepped as many steps with random actions (``sim``), the policy acting alone
    (``act``) and the bare update (``bare``). Measured round by round, the machine's drift
    between minutes hits ours and its limits alike."""
    torch.manual_seed(0)
    env = make_train_env(cfg)
    sim_env = make_train_env(cfg)
    sim_td = sim_env.reset()
    agent = agent_for_env(cfg, env)
    update = make_update(cfg, agent, env)
    collector = make_collector(cfg, env, agent)
    rounds = []
    t_collect = time.perf_counter()
    for i, batch in enumerate(collector):
        collect = time.perf_counter() - t_collect
        t0 = time.perf_counter()
        update.store(batch)
        t1 = time.perf_counter()
        update.update()
        t2 = time.perf_counter()
        r = {"frames": batch.numel(), "collect": collect, "advantages": t1 - t0, "update": t2 - t1}
        r["sim"], sim_td = sim_seconds(sim_env, sim_td, batch.shape[1])
        r["act"] = acting_only(agent, batch)
        minibatch = agent.encode(update.buffer.sample()).detach().clone()
        aux_batch = None  # one of the epoch's auxiliary minibatches (None while the memory is short)
        if update.aux is not None:
            aux_batch = next(update.aux.epoch(update.minibatches), None)
        r["bare"] = bare_update(update, minibatch, aux_batch)
        if i > 0:  # round 0 warms every part up
            rounds.append(r)
        if i == iterations:
            break
        t_collect = time.perf_counter()
    collector.shutdown()
    env.close()
    sim_env.close()
    return rounds


def peer_fps(peer: str, cfg, iterations: int) -> float | None:
    """frames/s of ``peer``'s PPO on our Gymnasium interface, or None when it is not installed."""
    package, runner = PEERS[peer]
    if importlib.util.find_spec(package) is None:
        return None
    with contextlib.redirect_stdout(io.StringIO()):  # their model summaries and per-iteration logs
        return runner(cfg, iterations)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("--exps", nargs="+", default=["bounce_ppo", "bounce_fd"])
    parser.add_argument("--num-envs", nargs="+", type=int, default=[256, 1024])
    parser.add_argument("--iterations", type=int, default=3, help="timed iterations (after one warm-up)")
    parser.add_argument("--no-peers", action="store_true", help="skip skrl and rsl_rl")
    parser.add_argument("--compile", action="store_true", help="agent.compile=true (torch.compile)")
    profiles = sorted(p.stem for p in resource_dir("conf").joinpath("profile").glob("*.yaml"))
    parser.add_argument("--profile", choices=profiles, help="a conf/profile on top of each exp (+profile=)")
    parser.add_argument(
        "--set",
        nargs="+",
        default=[],
        metavar="KEY=VALUE",
        help="more overrides for every exp, e.g. --set agent.critic_encoder_sizes=[256,128]",
    )
    args = parser.parse_args()
    logging.getLogger("torchrl").setLevel(logging.WARNING)
    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} torch threads, "
        f"OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY')}, "
        f"GOMP_SPINCOUNT={os.environ.get('GOMP_SPINCOUNT')}, "
        f"{args.iterations} timed iterations, "
        f"profile {args.profile or 'none (the exps as the paper has them)'}"
        + (f", overrides {' '.join(args.set)}" if args.set else "")
        + "; frames/s"
    )
    header = (
        f"{'exp':<11} {'N':>5} {'ours':>7} {'sim':>7} {'update':>7} {'limit':>7} {'ours/lim':>8} "
        f"{'act':>7} {'/lim+act':>8} {'lim range':>9} "
        f"{'collect':>7} {'adv':>5} {'upd':>5} "
        + " ".join(f"{p:>{PEER_WIDTH[p]}}" for p in PEERS)
        + f" {'ours/peer':>9} {'products':>8}"
    )
    print(header)
    print("-" * len(header))
    for exp in args.exps:
        for n in args.num_envs:
            overrides = [f"+exp={exp}"] + ([f"+profile={args.profile}"] if args.profile else [])
            overrides += [f"env.num_envs={n}", "logger.backend=none"]
            overrides += ["agent.compile=true"] if args.compile else []
            overrides += args.set
            cfg = checked_config(compose_train(overrides))
            for note in settle_for_machine(cfg):  # as train.py; its lines would split the table
                print(note, file=sys.stderr)
            rounds = measure(cfg, args.iterations)
            r = {k: sum(rnd[k] for rnd in rounds) for k in rounds[0]}  # totals over the rounds
            total = r["collect"] + r["advantages"] + r["update"]
            fps = r["frames"] / total
            sim, update, act = (r["frames"] / r[k] for k in ("sim", "bare", "act"))
            limit = r["frames"] / (r["sim"] + r["bare"])  # 1 / (1/sim + 1/update)
            with_acting = r["frames"] / (r["sim"] + r["bare"] + r["act"])
            per_round = [
                (rnd["sim"] + rnd["bare"]) / (rnd["collect"] + rnd["advantages"] + rnd["update"])
                for rnd in rounds
            ]
            peers = {p: None if args.no_peers else peer_fps(p, cfg, args.iterations) for p in PEERS}
            best = max((v for v in peers.values() if v), default=None)
            cells = " ".join(
                f"{v:>{PEER_WIDTH[p]},.0f}" if v else f"{'-':>{PEER_WIDTH[p]}}" for p, v in peers.items()
            )
            line = (
                f"{exp:<11} {n:>5} {fps:>7,.0f} {sim:>7,.0f} {update:>7,.0f} {limit:>7,.0f} "
                f"{fps / limit:>8.2f} {act:>7,.0f} {fps / with_acting:>8.2f} "
                f"{f'{min(per_round):.2f}-{max(per_round):.2f}':>9} "
                f"{r['collect'] / total:>7.0%} {r['advantages'] / total:>5.0%} "
                f"{r['update'] / total:>5.0%} {cells} "
                + (f"{fps / best:>9.2f}" if best else f"{'-':>9}")
                + f" {cfg.agent.precision!s:>8}"
            )
            print(line, flush=True)


if __name__ == "__main__":
    main()
