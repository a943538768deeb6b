"""A falling ceiling on the policy's standard deviation (``agent.std_ceiling``, off by default).

Why: on Bounce, plain PPO's standard deviation stays near 1 on actions in [-1, 1] (the KL rule
holds the rate at 2-4e-5 and nothing pulls the log-std down), so the sampled policy that PPO
optimises is mostly its noise and plateaus at 6-7 bounces per 10 s, while the noise-free
controller read out of it drifts and falls back from its peak (README, "Results on a CPU").
A ceiling that falls over training makes the sampled policy converge onto the controller, so
that PPO's objective is the controller's return. The ceiling falls log-linearly (the log-std
is the parameter) from the initial standard deviation to ``agent.std_ceiling`` over
``agent.std_ceiling_frames`` frames, then stays there.

How: projection. After every step of the PPO optimiser (a step post-hook) and whenever the
frame count moves (``StdCeiling.set_frames``) the log-std parameter is clamped to the
ceiling's log; below it, it learns as before. The parameter itself is what a checkpoint holds,
so an evaluation of a checkpoint sees the standard deviation the run had at its frames.
"""

from __future__ import annotations

import math

import torch

from roto_trl.utils.cli import is_number


def checked_std_ceiling(final, frames) -> tuple[float | None, int]:
    """``(agent.std_ceiling, agent.std_ceiling_frames)`` checked: a positive final standard
    deviation or None (off), and a positive frame count; a one-line error naming the fix."""
    if final is not None and not (is_number(final) and float(final) > 0):
        raise ValueError(f"agent.std_ceiling must be a standard deviation > 0 or null (off), got {final!r}")
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise ValueError(f"agent.std_ceiling_frames must be a positive integer, got {frames!r}")
    return (None if final is None else float(final)), frames


def std_ceiling(frames: float, start: float, final: float, over: float) -> float:
    """The ceiling after ``frames`` frames: ``start`` at 0, log-linear to ``final`` at ``over``
    frames, ``final`` after. E.g. ``std_ceiling(500_000, 1.0, 0.25, 1_000_000)`` is 0.5."""
    progress = min(max(frames / over, 0.0), 1.0)
    return math.exp((1.0 - progress) * math.log(start) + progress * math.log(final))


class StdCeiling:
    """Holds the policy's ``log_std`` parameter ``[n_actions]`` at or below ``log(ceiling)``.

    Args:
        log_std: the policy head's log standard deviation parameter.
        start: the ceiling at frame 0 (the initial standard deviation).
        final: the ceiling from ``over`` frames on.
        over: frames over which the ceiling falls.
    """

    def __init__(self, log_std: torch.nn.Parameter, start: float, final: float, over: int) -> None:
        self.log_std = log_std
        self.start, self.final, self.over = float(start), float(final), int(over)
        self.value = self.start

    def set_frames(self, frames: int) -> float:
        """Move the ceiling to ``frames`` and project the parameter under it; returns the ceiling."""
        self.value = std_ceiling(frames, self.start, self.final, self.over)
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
