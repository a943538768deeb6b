"""What each logged number is: a readable name and its unit, for plots, reports and tables.

``describe(key)`` covers the columns of ``train.csv`` and ``eval.csv`` and the physical metrics
(docs/training.md lists them all); a key it does not know is shown as it is, without a unit.
"""

from __future__ import annotations

import re

# exact keys -> (name, unit); "" is a number without a unit
NAMES: dict[str, tuple[str, str]] = {
    "return_mean": ("evaluation return", "sum of rewards"),
    "return_std": ("evaluation return, std over episodes", "sum of rewards"),
    "latent_rank": ("policy latent's effective rank", "directions"),
    "time": ("evaluation time", "s"),
    "object_distance": ("final distance to the sphere", "m"),
    "bounces": ("bounces per episode", "count"),
    "bounces_per_10s": ("bounces per 10 s", "per 10 s"),
    "rotations": ("complete rotations per episode", "count"),
    "rotations_per_10s": ("complete rotations per 10 s", "per 10 s"),
    "turns": ("turns of the ball pair per episode (signed)", "turns"),
    "turns_per_10s": ("turns of the ball pair per 10 s", "per 10 s"),
    "reward": ("reward per step", "reward"),
    "episode_return": ("training episode return", "sum of rewards"),
    "episodes": ("training episodes ended", "count"),
    "loss_objective": ("PPO's clipped objective (loss)", ""),
    "loss_critic": ("value loss (scaled)", ""),
    "loss_entropy": ("entropy bonus (loss)", ""),
    "entropy": ("policy entropy, sum over action dimensions", "nats"),
    "kl_approx": ("approximate KL, mean over minibatches", "nats"),
    "kl_k3": ("KL (k3 estimate), mean over minibatches", "nats"),
    "kl_k3_median": ("KL (k3 estimate), median over minibatches", "nats"),
    "clip_fraction": ("clipped ratio fraction", "fraction"),
    "clip_fraction_median": ("clipped ratio fraction, median over minibatches", "fraction"),
    "grad_norm": ("gradient norm before clipping", ""),
    "lr": ("learning rate", ""),
    "mean_saturation": ("policy mean's entries past 0.9", "fraction"),
    "fps": ("training speed", "frames/s"),
    "wall_time": ("wall time", "s"),
    "time/collect": ("collection time per iteration", "s"),
    "time/update": ("update time per iteration", "s"),
    "time/eval_share": ("evaluation's share of the wall time", "fraction"),
    "aux_loss": ("auxiliary loss (scaled by c_aux)", ""),
}
# patterns -> (name template, unit); the groups fill the name
PATTERNS: tuple[tuple[str, str, str], ...] = (
    (r"reached_(.+)", "episodes that came within {0}", "fraction"),
    (r"find_time_(.+)", "time to come within {0}", "s"),
    (r"episode/(.+)", "training episodes: {0}", ""),
    (r"reward/(.+)", "reward term {0} per step", "reward"),
    (r"aux/(.+)", "auxiliary {0}", ""),
)


def describe(key: str) -> tuple[str, str]:
    """``(name, unit)`` of a logged ``key``; ``(key, "")`` when it is not known."""
    if key in NAMES:
        return NAMES[key]
    for pattern, template, unit in PATTERNS:
        found = re.fullmatch(pattern, key)
        if found:
            inner = found.group(1)
            if pattern.startswith("episode/"):
                name, inner_unit = describe(inner)
                return f"training episodes: {name}", inner_unit
            return template.format(inner), unit
    return key, ""


def label(key: str) -> str:
    """``"name (unit)"``, or the name alone for a number without a unit: an axis label."""
    name, unit = describe(key)
    return f"{name} ({unit})" if unit else name
