"""A run's progress (``TrainState``) and its random generators, as checkpoints keep them."""

from __future__ import annotations

import random
from dataclasses import dataclass, field

import numpy as np
import torch

from roto_trl.trainers.schedule import EvalClock


@dataclass
class TrainState:
    """Where a run stands: frames and iterations trained, the evaluation ``best.pt`` holds, and
    its clocks (wall time of earlier sittings, time spent evaluating)."""

    frames: int = 0
    iteration: int = 0
    best_eval: dict[str, float] | None = None
    wall_before: float = 0.0  # wall seconds of the sittings before this one
    eval_clock: EvalClock = field(default_factory=EvalClock)

    def state_dict(self, wall: float) -> dict:
        """The checkpoint's progress entries, ``wall`` being the run's wall time so far."""
        return {
            "frames": self.frames,
            "iteration": self.iteration,
            "best_eval_metrics": self.best_eval,
            "wall_time": wall,
            "eval_time": self.eval_clock.seconds,
        }

    def load_state_dict(self, state: dict) -> None:
        self.frames, self.iteration = int(state["frames"]), int(state["iteration"])
        self.best_eval = state["best_eval_metrics"]
        self.wall_before = float(state["wall_time"])
        self.eval_clock = EvalClock(state["eval_time"])


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def rng_state(env) -> dict:
    """The generators a resumed run must continue: torch's, numpy's, Python's and the env's resets."""
    return {
        "torch": torch.get_rng_state(),
        "numpy": np.random.get_state(),
        "python": random.getstate(),
        "env": env.base_env.rng.bit_generator.state,
    }


def set_rng_state(state: dict, env) -> None:
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
    env.base_env.rng.bit_generator.state = state["env"]
