"""When training evaluates, and what evaluation costs: evaluation is scheduled by frames.

Scheduling by frames (``eval.every_frames``) rather than by iterations keeps a run's curve points
at the same frames whatever its worlds and rollout length, so runs of different sizes compare
point by point, and keeps evaluation's share of the wall time predictable.
"""

from __future__ import annotations

import time

from omegaconf import DictConfig


def frames_per_iteration(cfg: DictConfig) -> int:
    """Frames one iteration collects: ``env.num_envs x agent.rollout_len``."""
    return int(cfg.env.num_envs) * int(cfg.agent.rollout_len)


def evaluation_due(frames_before: int, frames_after: int, every_frames: int) -> bool:
    """Whether an iteration that took the frame count from ``frames_before`` to ``frames_after``
    crossed a multiple of ``every_frames`` (evaluations land on the first iteration at or past
    each multiple, so a run evaluates about ``total_frames / every_frames`` times)."""
    return frames_after // every_frames > frames_before // every_frames


def evaluations_left(frames: int, total_frames: int, every_frames: int) -> int:
    """Scheduled evaluations (``evaluation_due``) between ``frames`` and ``total_frames``."""
    return total_frames // every_frames - frames // every_frames


class EvalClock:
    """Seconds spent evaluating during a run, to report evaluation's share of the wall time.

    Args:
        seconds: evaluation time of the run so far (a resumed run's, from its checkpoint).
    """

    def __init__(self, seconds: float = 0.0) -> None:
        self.seconds = float(seconds)
        self.last = 0.0  # seconds of the latest evaluation
        self._start: float | None = None

    def __enter__(self) -> EvalClock:
        self._start = time.perf_counter()
        return self

    def __exit__(self, *exc) -> None:
        self.last = time.perf_counter() - self._start
        self.seconds += self.last

    def share(self, wall: float) -> float:
        """Evaluation's fraction of ``wall`` seconds (0 before any time has passed)."""
        return self.seconds / wall if wall > 0 else 0.0
