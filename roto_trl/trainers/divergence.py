"""Telling a run that diverges from one that learns slowly (``divergence.*`` in the config).

An iteration diverges when the mean gradient norm before clipping or the magnitude of PPO's
losses leaves the range any learning run keeps to (the bounds are a hundred times and more the
largest values of the shipped experiments' runs, docs/training.md), or when the policy's mean is
saturated on nearly every action and its KL to the rollout's policy is zero: a policy that can no
longer change. The first diverging iteration prints one warning line; ``divergence.stop_after``
diverging iterations in a row stop the run (``DivergedError``: exit status 3, the last checkpoint
kept), null only warns.
"""

from __future__ import annotations

from dataclasses import dataclass

from omegaconf import DictConfig

from roto_trl.trainers.errors import DivergedError

SATURATED_SHARE = 0.99  # mean_saturation above this ...
STILL_KL = 1e-8  # ... with the median KL under this: a policy that no longer changes
HARMLESS = {
    "grad_norm": 0.0,
    "loss_critic": 0.0,
    "loss_objective": 0.0,
    "mean_saturation": 0.0,
    "kl_k3_median": 1.0,
}


@dataclass
class DivergenceWatch:
    """Counts diverging iterations in a row; ``grad_norm`` and ``loss`` are the bounds,
    ``stop_after`` the count that stops the run (None: never)."""

    grad_norm: float
    loss: float
    stop_after: int | None
    streak: int = 0
    warned: bool = False

    @classmethod
    def from_config(cls, cfg: DictConfig) -> DivergenceWatch:
        d = cfg.divergence
        return cls(d.grad_norm, d.loss, d.stop_after)

    def reason(self, stats: dict[str, float]) -> str | None:
        """Why the iteration of ``stats`` (a ``train.csv`` row) diverges, or None."""
        row = HARMLESS | stats  # what an iteration did not log counts as harmless
        if row["grad_norm"] > self.grad_norm:
            return f"the gradient norm is {row['grad_norm']:.3g} (divergence.grad_norm={self.grad_norm:g})"
        for key in ("loss_critic", "loss_objective"):
            if abs(row[key]) > self.loss:
                return f"{key} is {abs(row[key]):.3g} (divergence.loss={self.loss:g})"
        if row["mean_saturation"] > SATURATED_SHARE and row["kl_k3_median"] < STILL_KL:
            share, kl = row["mean_saturation"], row["kl_k3_median"]
            return f"the policy's mean is saturated on {share:.0%} of its actions and its KL is {kl:.1e}"
        return None

    def check(self, stats: dict[str, float], frames: int) -> str | None:
        """Count the iteration; a warning line for the first diverging one (None otherwise), a
        ``DivergedError`` after ``stop_after`` in a row."""
        reason = self.reason(stats)
        self.streak = self.streak + 1 if reason else 0
        if reason and self.stop_after is not None and self.streak >= self.stop_after:
            raise DivergedError(
                f"diverged for {self.streak} iterations in a row at {frames:,} frames: {reason}; try a "
                "smaller agent.lr or ssl.coeff (divergence.stop_after=null only warns)"
            )
        if reason and not self.warned:
            self.warned = True
            fix = "try a smaller agent.lr or ssl.coeff"
            return f"warning: the run diverges at {frames:,} frames: {reason}; {fix}"
        return None
