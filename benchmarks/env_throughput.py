"""Control steps per second of each task, beside raw ``mujoco.rollout`` on the same model.

For every task, N and thread count it times, in the same process and one after the other:
  env    ``make_env(...)`` (transforms included) stepped with uniform random actions in [-1, 1]
         through ``step_and_maybe_reset`` (episodes end and partially reset as in training);
  raw    ``mujoco.rollout`` on the same compiled model with the same substeps, one call per
         control step, replaying each env step from the state it started from with the random
         controls the env applied: the same physics without the env around it;
  gym    ``gymnasium.make_vec("RoTO/<Task>-v0")`` stepped with random actions (numpy in and out,
         same-step autoreset): the Gymnasium interface's cost on top of the env.
Rounds alternate (median reported) so that drift in the machine's speed hits all three. The
ratio env / raw is the figure of merit (goal: >= 0.9 at N=256 and 1024, 2 threads).

With ``--breakdown`` it prints instead where an env step's wall time goes, in microseconds per
control step (each part without the parts it calls): the physics (``mujoco.rollout``, the reset
worlds' settling step included), our env's step and reset outside the physics, the transforms'
steps and resets (ours, which build ``prop``, apart from ``CatFrames`` and ``BinariseContacts``,
which the design card keeps), and TorchRL's own bookkeeping (``EnvBase.step``,
``TransformedEnv``, ``maybe_reset``, ``step_mdp``). The parts outside the physics are Python on
the main thread. Two more columns say what that means for env / raw: ``budget``, the time outside
the physics that env / raw = 0.9 leaves (physics / 9; an upper bound, since the physics includes
the reset worlds' settling steps that the raw rollout does not replay), and ``card floor``, what
the design card's parts take by themselves (the kept transforms plus TorchRL's bookkeeping):
where the floor exceeds the budget, no change to our own code can reach 0.9.
They too move with the machine's state: on the 2-core VM the same Python took about twice as
long right after a 15 ms stretch of physics (or of anything else) as when run back to back, so
compare code changes by alternating runs of the two versions, not against an old table.

    python benchmarks/env_throughput.py      # the full table (several minutes)
    python benchmarks/env_throughput.py --tasks bounce --num-envs 1024 --threads 2
    python benchmarks/env_throughput.py --tasks bounce --num-envs 256 --threads 2 --breakdown
    python benchmarks/env_throughput.py --tasks bounce --num-envs 256 --threads 2 --breakdown --no-physics
"""

from __future__ import annotations

import argparse
import functools
import time
from collections import defaultdict

import roto_trl  # noqa: F401  first, before torch loads: sets how its OpenMP threads wait (roto_trl/__init__.py)

# isort: split
import gymnasium
import mujoco
import numpy as np
import torch
from mujoco import rollout as mj_rollout
from torchrl.envs import CatFrames

from roto_trl import TASKS, make_env
from roto_trl.envs.batched_mujoco import FULL_PHYSICS
from roto_trl.envs.registration import ENV_IDS
from roto_trl.transforms import BinariseContacts


class RawRollout:
    """Bare ``mujoco.rollout`` of one control step per call: the baseline.

    It replays the env's steps: from the state each env step started from (after any reset) with
    the controls the env applied, so that both do the same physics, the env's resets included.
    """

    def __init__(self, model: mujoco.MjModel, threads: int, substeps: int, num_envs: int, control_spec: int):
        self.pool = mj_rollout.Rollout(nthread=threads if threads > 1 else 0)
        self.datas = [mujoco.MjData(model) for _ in range(threads)]
        self.models = [model] * num_envs
        self.substeps = substeps
        self.control_spec = control_spec  # ctrl, plus mocap positions where the scene has them
        self.state_out = np.empty((num_envs, substeps, mujoco.mj_stateSize(model, FULL_PHYSICS)))
        self.sensor_out = np.empty((num_envs, substeps, model.nsensordata))

    def run(self, steps: list[tuple[np.ndarray, np.ndarray]]) -> float:
        """Control steps/s over ``steps``: (state ``[N, nstate]``, ctrl ``[N, substeps, nu]``) pairs."""
        start = time.perf_counter()
        for state, ctrl in steps:
            self.pool.rollout(
                self.models,
                self.datas,
                state,
                ctrl,
                control_spec=self.control_spec,
                skip_checks=True,
                nstep=self.substeps,
                state=self.state_out,
                sensordata=self.sensor_out,
            )
        return len(steps) * len(self.models) / (time.perf_counter() - start)


def gym_round(envs, steps: int, rng: np.random.Generator) -> float:
    """Control steps/s of the Gymnasium vector env over ``steps`` random steps."""
    shape = envs.action_space.shape
    elapsed = 0.0
    for _ in range(steps):
        actions = rng.uniform(-1.0, 1.0, size=shape).astype(np.float32)
        start = time.perf_counter()
        envs.step(actions)
        elapsed += time.perf_counter() - start
    return steps * shape[0] / elapsed


def measure(task: str, num_envs: int, threads: int, steps: int, rounds: int) -> tuple[float, float, float]:
    """Median control steps/s of (raw, env, gym) over alternating rounds, so drift hits all."""
    env = make_env(task, num_envs, seed=0, num_threads=threads)
    base = env.base_env
    raw = RawRollout(base.mj_model, threads, base.substeps, num_envs, base._control_spec)
    envs = gymnasium.make_vec(ENV_IDS[task], num_envs=num_envs, num_threads=threads)
    envs.reset(seed=0)
    rng = np.random.default_rng(0)
    gen = torch.Generator().manual_seed(0)
    td = env.reset()
    raw_sps, env_sps, gym_sps = [], [], []
    for round_ in range(rounds + 1):  # round 0 warms up
        recorded, elapsed = [], 0.0
        for _ in range(steps):
            td.set("action", torch.rand(num_envs, base.n_actions, generator=gen) * 2 - 1)
            state = base._state.copy()
            start = time.perf_counter()
            _, td = env.step_and_maybe_reset(td)
            elapsed += time.perf_counter() - start
            recorded.append((state, base._ctrl.copy()))
        raw_rate = raw.run(recorded)
        gym_rate = gym_round(envs, steps, rng)
        if round_:
            env_sps.append(steps * num_envs / elapsed)
            raw_sps.append(raw_rate)
            gym_sps.append(gym_rate)
    env.close()
    envs.close()
    raw.pool.close()
    return float(np.median(raw_sps)), float(np.median(env_sps)), float(np.median(gym_sps))


class SectionTimer:
    """Wall time of named sections, each without the time of the sections it calls (ns)."""

    def __init__(self) -> None:
        self.exclusive: dict[str, int] = defaultdict(int)
        self._children: list[int] = []

    def wrap(self, obj, method: str, label: str) -> None:
        """Time ``obj.method`` as ``label`` from now on (an instance attribute shadows the class's)."""
        inner = getattr(obj, method)

        @functools.wraps(inner)
        def timed(*args, **kwargs):
            self._children.append(0)
            start = time.perf_counter_ns()
            try:
                return inner(*args, **kwargs)
            finally:
                elapsed = time.perf_counter_ns() - start
                self.exclusive[label] += elapsed - self._children.pop()
                if self._children:
                    self._children[-1] += elapsed

        setattr(obj, method, timed)


BREAKDOWN_PARTS = (
    "physics",
    "env step (ours)",
    "env reset (ours)",
    "transforms: ours",
    "transforms: kept",
    "TorchRL bookkeeping",
)
# the transforms the design card keeps (TorchRL envs "with CatFrames and binarisation transforms")
CARD_TRANSFORMS = (CatFrames, BinariseContacts)
CARD_PARTS = ("transforms: kept", "TorchRL bookkeeping")


def breakdown(
    task: str, num_envs: int, threads: int, steps: int, physics: bool = True
) -> tuple[dict[str, float], float]:
    """Microseconds per control step of each part of ``step_and_maybe_reset``, and the share of
    steps on which some world reset, over ``steps`` steps with random actions after a warm-up.

    With ``physics=False`` the rollout call only copies each world's state to its outputs (the
    worlds stay where they are, so only truncations reset): the Python parts then run back to
    back, as in a micro-benchmark.
    """
    env = make_env(task, num_envs, seed=0, num_threads=threads)
    base = env.base_env
    if not physics:

        def frozen(state, controls, state_out, sensor_out):
            state_out[:] = state[:, None]
            sensor_out[:] = 0.0

        base._rollout = frozen
    timer = SectionTimer()
    timer.wrap(env, "step_and_maybe_reset", "TorchRL bookkeeping")
    timer.wrap(base, "_rollout", "physics")
    timer.wrap(base, "_step", "env step (ours)")
    timer.wrap(base, "_reset", "env reset (ours)")
    for transform in env.transform:
        label = "transforms: kept" if isinstance(transform, CARD_TRANSFORMS) else "transforms: ours"
        timer.wrap(transform, "_step", label)
        timer.wrap(transform, "_reset", label)
    resets = [0]
    on_reset = base._on_reset_mask

    def count_reset(idx):
        resets[0] += 1
        return on_reset(idx)

    base._on_reset_mask = count_reset
    gen = torch.Generator().manual_seed(0)
    td = env.reset()
    for warm_up in (True, False):
        timer.exclusive.clear()
        resets[0] = 0
        for _ in range(max(steps // 4, 10) if warm_up else steps):
            td.set("action", torch.rand(num_envs, base.n_actions, generator=gen) * 2 - 1)
            _, td = env.step_and_maybe_reset(td)
    env.close()
    return {part: timer.exclusive[part] / steps / 1e3 for part in BREAKDOWN_PARTS}, resets[0] / steps


def print_breakdowns(args: argparse.Namespace) -> None:
    """The ``--breakdown`` table: microseconds per control step of each part."""
    short = ("physics", "ours step", "ours reset", "tf ours", "tf kept", "torchrl")
    header = (
        f"{'task':<8} {'N':>5} {'thr':>3} {'resets':>6} "
        + " ".join(f"{name:>10}" for name in short)
        + f" {'outside':>8} {'phys share':>10} {'budget':>7} {'card floor':>10}"
    )
    print(
        "microseconds per control step (median of rounds); 'resets': share of steps with a reset; "
        "budget: physics / 9 (outside time env / raw 0.9 allows); card floor: tf kept + torchrl"
    )
    print(header)
    print("-" * len(header))
    for task in args.tasks:
        for n in args.num_envs:
            for threads in args.threads:
                rounds = [
                    breakdown(task, n, threads, args.steps, physics=not args.no_physics)
                    for _ in range(args.rounds)
                ]
                parts = {p: float(np.median([r[0][p] for r in rounds])) for p in BREAKDOWN_PARTS}
                reset_share = float(np.median([r[1] for r in rounds]))
                outside = sum(v for p, v in parts.items() if p != "physics")
                share = parts["physics"] / (parts["physics"] + outside)
                floor = sum(parts[p] for p in CARD_PARTS)
                print(
                    f"{task:<8} {n:>5} {threads:>3} {reset_share:>6.2f} "
                    + " ".join(f"{parts[p]:>10,.0f}" for p in BREAKDOWN_PARTS)
                    + f" {outside:>8,.0f} {share:>10.2f} {parts['physics'] / 9:>7,.0f} {floor:>10,.0f}",
                    flush=True,
                )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("--tasks", nargs="+", default=sorted(TASKS), choices=sorted(TASKS))
    parser.add_argument("--num-envs", nargs="+", type=int, default=[256, 1024, 4096])
    parser.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--steps", type=int, default=30, help="timed control steps per round")
    parser.add_argument("--rounds", type=int, default=3, help="alternating timing rounds per cell")
    parser.add_argument(
        "--breakdown", action="store_true", help="print where a step's time goes instead of the rates"
    )
    parser.add_argument(
        "--no-physics",
        action="store_true",
        help="with --breakdown: the rollout only copies the state, to time the Python parts back to back",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.no_physics and not args.breakdown:
        parser.error("--no-physics only applies with --breakdown")
    if args.breakdown:
        print_breakdowns(args)
        return

    print(f"mujoco {mujoco.__version__}, torch {torch.__version__}, control steps/s (N x steps / s)")
    header = (
        f"{'task':<8} {'N':>5} {'thr':>3} {'raw rollout':>12} {'roto env':>10} {'env/raw':>8}"
        f" {'gymnasium':>10} {'gym/env':>8}"
    )
    print(header)
    print("-" * len(header))
    for task in args.tasks:
        for n in args.num_envs:
            for threads in args.threads:
                raw_sps, env_sps, gym_sps = measure(task, n, threads, args.steps, args.rounds)
                print(
                    f"{task:<8} {n:>5} {threads:>3} {raw_sps:>12,.0f} {env_sps:>10,.0f} "
                    f"{env_sps / raw_sps:>8.2f} {gym_sps:>10,.0f} {gym_sps / env_sps:>8.2f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
