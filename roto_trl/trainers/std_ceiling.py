"""A falling ceiling on the policy's standard deviation (``agent.std_ceiling``; off by default,
0.3 in ``find_ppo``'s part of ``+profile=cpu``).

Why: on Bounce, plain PPO's standard deviation stays near 1 on actions in [-1, 1] (the KL rule
holds the rate at 2-4e-5 and nothing pulls the log-std down), so the sampled policy that PPO
optimises is mostly its noise and plateaus at 6-7 bounces per 10 s, while the noise-free
controller read out of it falls back from its peak. A ceiling that falls over training makes
the sampled policy converge onto the controller, so that PPO's objective is the controller's
return. The ceiling stays at the initial standard deviation up to the first of
``agent.std_ceiling_frames`` ``[begin, end]``, falls log-linearly (the log-std is the
parameter) to ``agent.std_ceiling`` at ``end``, then stays there; the window defaults to
fractions ``[0.6, 0.9]`` of ``total_frames`` (a resumed run given more ``total_frames`` moves a
fractional window with it). What it did on Bounce (3 seeds each, README "Results on a CPU"):
falling from frame 0 found no bouncing by 0.5 M frames; falling from 0.5 M to 0.3 at 1.5 M (of
2 M) doubled the sampled policy's bounces, but the controller still fell back on 2 seeds of 3
(and the sampled policy with it on one), so it is off there. On Find the late window (1 up to
0.6 of the run, 0.3 from 0.9) held all 7 ``find_ppo`` seeds and raised their final controllers
(0.50 against 0.45 within 3 cm), so ``find_ppo``'s CPU recipe has it; it lowered ``find_fd``'s.

How: projection. After every step of the PPO optimiser (a step post-hook) and whenever the
frame count moves (``StdCeiling.set_frames``) the log-std parameter is clamped to the
ceiling's log; below it, it learns as before. The parameter itself is what a checkpoint holds,
so an evaluation of a checkpoint sees the standard deviation the run had at its frames.
"""

from __future__ import annotations

import math

import torch

from roto_trl.utils.cli import is_number, number_pair

DEFAULT_FRAMES = (0.6, 0.9)  # ppo.yaml's (fractions of total_frames); configs saved before the option lack it


def checked_std_ceiling(final, frames, total_frames: int) -> tuple[float | None, tuple[int, int]]:
    """``(agent.std_ceiling, agent.std_ceiling_frames)`` checked: a positive final standard
    deviation or None (off), and the window ``[begin, end]`` in frames with 0 <= begin < end.
    The window is either frames (two ints, e.g. ``[500000, 1500000]``) or fractions of
    ``total_frames`` (numbers in [0, 1], at least one written with a point, e.g. ``[0.6, 0.9]``),
    so that one window fits runs of any length; fractions come back as frames. A one-line error
    naming the fix otherwise."""
    if final is not None and not (is_number(final) and float(final) > 0):
        raise ValueError(f"agent.std_ceiling must be a standard deviation > 0 or null (off), got {final!r}")
    pair = number_pair(frames)
    if pair is not None and any(isinstance(f, float) for f in pair) and all(0 <= f <= 1 for f in pair):
        pair = (round(pair[0] * total_frames), round(pair[1] * total_frames))
    if pair is None or not (all(isinstance(f, int) for f in pair) and 0 <= pair[0] < pair[1]):
        raise ValueError(
            f"agent.std_ceiling_frames must be [begin, end] frames with 0 <= begin < end, e.g. "
            f"[500000,1500000], or fractions of total_frames, e.g. [0.6,0.9]; got {frames!r}"
        )
    return (None if final is None else float(final)), (pair[0], pair[1])


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
