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
ratio env / raw is the figure of merit (goal: >= 0.9 at N=1024, 2 threads).

    python benchmarks/env_throughput.py      # the full table (several minutes)
    python benchmarks/env_throughput.py --tasks bounce --num-envs 1024 --threads 2
"""

from __future__ import annotations

import argparse
import time

import gymnasium
import mujoco
import numpy as np
import torch
from mujoco import rollout as mj_rollout

from roto_trl import TASKS, make_env
from roto_trl.envs.batched_mujoco import FULL_PHYSICS
from roto_trl.envs.registration import ENV_IDS


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("--tasks", nargs="+", default=sorted(TASKS), choices=sorted(TASKS))
    parser.add_argument("--num-envs", nargs="+", type=int, default=[256, 1024, 4096])
    parser.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--steps", type=int, default=30, help="timed control steps per round")
    parser.add_argument("--rounds", type=int, default=3, help="alternating timing rounds per cell")
    args = parser.parse_args()
    torch.set_num_threads(1)

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
