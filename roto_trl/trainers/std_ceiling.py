"""A falling ceiling on the policy's standard deviation (``agent.std_ceiling``; off by default).

Why: at a few hundred worlds PPO barely moves the policy's standard deviation from its initial
1 on actions in [-1, 1], so the sampled policy that PPO optimises is mostly noise while the
noise-free controller read out of it (the evaluation action) is what a run is judged by. A
ceiling that falls late in the run makes the sampled policy converge onto the controller. The
ceiling stays at the initial standard deviation up to ``WINDOW[0]`` of ``total_frames``, falls
log-linearly (the log-std is the parameter) to ``agent.std_ceiling`` at ``WINDOW[1]``, then stays
there. Measurements of the ceiling and its window: docs/recipe.md.

How: projection. After every step of the PPO optimiser (a step post-hook) and whenever the
frame count moves (``StdCeiling.set_frames``) the log-std parameter is clamped to the
ceiling's log; below it, it learns as before. The parameter itself is what a checkpoint holds,
so an evaluation of a checkpoint sees the standard deviation the run had at its frames.
"""

from __future__ import annotations

import math

import torch

WINDOW = (0.6, 0.9)  # the fractions of total_frames over which the ceiling falls


def std_ceiling(frames: float, start: float, final: float, begin: float, end: float) -> float:
    """The ceiling after ``frames`` frames: ``start`` up to ``begin``, log-linear to ``final`` at
    ``end``, ``final`` after. E.g. ``std_ceiling(1_000_000, 1.0, 0.25, 500_000, 1_500_000)`` is 0.5."""
    progress = min(max((frames - begin) / (end - begin), 0.0), 1.0)
    return math.exp((1.0 - progress) * math.log(start) + progress * math.log(final))


class StdCeiling:
    """Holds the policy's ``log_std`` parameter ``[n_actions]`` at or below ``log(ceiling)``.

    Args:
        log_std: the policy head's log standard deviation parameter.
        start: the ceiling up to ``begin`` frames (the initial standard deviation).
        final: the ceiling from ``end`` frames on.
        begin, end: the frames between which the ceiling falls.
    """

    def __init__(self, log_std: torch.nn.Parameter, start: float, final: float, begin: int, end: int) -> None:
        self.log_std = log_std
        self.start, self.final, self.begin, self.end = float(start), float(final), int(begin), int(end)
        self.value = self.start

    @classmethod
    def over_run(
        cls, log_std: torch.nn.Parameter, start: float, final: float, total_frames: int
    ) -> StdCeiling:
        """The ceiling that falls over ``WINDOW`` of a run of ``total_frames`` frames."""
        begin, end = (round(f * total_frames) for f in WINDOW)
        return cls(log_std, start, final, begin, end)

    def set_frames(self, frames: int) -> float:
        """Move the ceiling to ``frames`` and project the parameter under it; returns the ceiling."""
        self.value = std_ceiling(frames, self.start, self.final, self.begin, self.end)
        self.project()
        return self.value

    @torch.no_grad()
    def project(self, *_) -> None:
        """Clamp the log-std to the ceiling (also the optimiser's step post-hook: ``*_`` are the
        hook's optimiser, args and kwargs)."""
        self.log_std.clamp_(max=math.log(self.value))

    def attach(self, optimizer: torch.optim.Optimizer) -> StdCeiling:
        """Project after every step of ``optimizer``; returns self."""
        optimizer.register_step_post_hook(self.project)
        return self
