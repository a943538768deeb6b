"""A run's progress bar that moves while the collector steps, with one speed and the time left.

A long run's first iteration can take minutes (4096 worlds x 32 steps); a bar updated once per
iteration would show nothing until then. The bar here moves by one step of every world each
time the policy acts during collection (a forward hook on the policy, active only while the
loop collects, so evaluation episodes do not count). Its speed is the training frames per
second of this sitting (evaluations left out), and the time left is the frames still to train at
that speed plus the evaluations still due at the last one's duration (``time_to_budget``);
tqdm's own rate and estimate, which follow the bar's jumps, are not shown.
"""

from __future__ import annotations

import torch
from tqdm import tqdm


def format_duration(seconds: float) -> str:
    """``3h 05m``, ``4m 10s`` or ``12s``."""
    seconds = max(0, round(seconds))
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    if hours:
        return f"{hours}h {minutes:02d}m"
    return f"{minutes}m {secs:02d}s" if minutes else f"{secs}s"


def estimate_line(remaining_frames: int, fps: float, evals_left: int, eval_seconds: float) -> str:
    """The first iteration's line: speed and time to the budget. ``eval_seconds`` 0 means no
    evaluation has been timed yet (a resumed run before its first one): the line says so rather
    than counting them as free."""
    eta = format_duration(time_to_budget(remaining_frames, fps, evals_left, eval_seconds))
    if not evals_left:
        evals = "no evaluation left"
    elif eval_seconds > 0:
        evals = f"{evals_left} evaluations of {eval_seconds:.1f} s"
    else:
        evals = f"{evals_left} evaluations not yet timed"
    return (
        f"speed: {fps:,.0f} frames/s (first iteration); {remaining_frames:,} frames to the budget: "
        f"about {eta} with {evals}"
    )


def time_to_budget(remaining_frames: int, fps: float, evals_left: int, eval_seconds: float) -> float:
    """Seconds to train ``remaining_frames`` at ``fps`` plus ``evals_left`` evaluations of
    ``eval_seconds`` each."""
    return remaining_frames / fps + evals_left * eval_seconds


class TrainingProgress:
    """The bar of a run from ``frames`` to ``total_frames``, stepped by ``num_envs`` per collected step.

    Args:
        total_frames: the run's frame budget.
        frames: frames already done (a resumed run's).
        num_envs: training worlds: frames per collected step.
        enabled: draw the bar (the estimate line is printed either way).
    """

    def __init__(self, total_frames: int, frames: int, num_envs: int, enabled: bool) -> None:
        self.bar = tqdm(
            total=total_frames,
            initial=frames,
            unit="frames",
            unit_scale=True,
            disable=not enabled,
            bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]",
        )
        self.start_frames = int(frames)
        self.total_frames = int(total_frames)
        self.num_envs = int(num_envs)
        self.collecting = False
        self.postfix: dict[str, str] = {}
        self._estimated = False

    def watch(self, policy: torch.nn.Module) -> torch.utils.hooks.RemovableHandle:
        """Move the bar each time ``policy`` acts while :attr:`collecting` is set."""
        return policy.register_forward_hook(self._on_policy_step)

    def _on_policy_step(self, module, args, output) -> None:
        if self.collecting:
            self.bar.update(self.num_envs)

    def iteration_done(
        self, frames: int, fps: float, evals_left: int, eval_seconds: float, train_seconds: float = 0.0
    ) -> None:
        """Set the bar to ``frames`` with the sitting's training speed and the time left
        (``train_seconds``: this sitting's wall time without its evaluations); after the first
        timed iteration print the expected speed and the time to the budget (training at ``fps``
        plus ``evals_left`` evaluations)."""
        self.bar.n = frames
        remaining = max(0, self.total_frames - frames)
        speed = (frames - self.start_frames) / train_seconds if train_seconds > 0 else fps
        if speed > 0:
            self.postfix["speed"] = f"{speed:,.0f} frames/s"
            self.postfix["left"] = format_duration(time_to_budget(remaining, speed, evals_left, eval_seconds))
        self.bar.set_postfix(self.postfix, refresh=False)
        self.bar.refresh()
        if not self._estimated and fps > 0:
            self._estimated = True
            remaining = max(0, self.total_frames - frames)
            self.bar.write(estimate_line(remaining, fps, evals_left, eval_seconds))

    def close(self) -> None:
        self.bar.close()
