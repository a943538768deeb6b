"""An exponential moving average of the policy's weights, the controller a run is evaluated with
when ``agent.policy_ema_decay`` > 0.

Why: on Bounce the noise-free controller (the policy's mean) of plain PPO swings from one
evaluation to the next and ends below its best, while the sampled policy that PPO optimises
plateaus; an average of recent weights is the classic remedy for a final iterate that jitters
around a good solution (Polyak averaging). Training never reads the average: PPO collects and
updates with the current weights; evaluations in training (and so ``best.pt``'s choice) and
``evaluate.py`` use the average.

The average covers the policy's encoder and head (log-std included): the parameters named
``encoder.*`` and ``policy_head.*`` in the agent's state dict, under which names a checkpoint
stores it (``POLICY_AVERAGE_KEY``); ``load_policy_weights`` puts it into an agent.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext

import torch

from roto_trl.utils.cli import is_number

POLICY_AVERAGE_KEY = "policy_average"  # a checkpoint's entry: {agent state-dict name: tensor}
POLICY_PREFIXES = ("encoder.", "policy_head.")


def checked_decay(decay) -> float:
    """``decay`` as a float in [0, 1) (None: 0, off), or a one-line error naming the fix."""
    if decay is None:
        return 0.0
    if not (is_number(decay) and 0.0 <= float(decay) < 1.0):
        raise ValueError(
            f"agent.policy_ema_decay must be a number in [0, 1) (0: off; 0.9: about the last 10 "
            f"iterations), got {decay!r}"
        )
    return float(decay)


def span_note(decay: float, iterations: int) -> str | None:
    """A one-line note when the average of ``decay`` spans more than half of a run of
    ``iterations`` iterations (its evaluations would mostly see the initial weights), naming the
    decay that spans a tenth of the run; None when the span fits (or there is no average)."""
    span = round(1.0 / (1.0 - decay), 6) if decay > 0.0 else 0.0  # 1 / (1 - 0.9) is 10.000000000000002
    if span <= iterations / 2:
        return None
    fix = (
        f"agent.policy_ema_decay={1.0 - 10.0 / iterations:.2f} averages about a tenth of the run"
        if iterations >= 20
        else "a run this short needs no average: agent.policy_ema_decay=0"
    )
    return (
        f"agent.policy_ema_decay={decay:g} averages about {span:.0f} iterations but "
        f"this run has {iterations}: its evaluations mostly see the initial weights ({fix})"
    )


def policy_parameters(agent: torch.nn.Module) -> dict[str, torch.nn.Parameter]:
    """The policy's parameters by their names in ``agent.state_dict()``: encoder and head."""
    return {name: p for name, p in agent.named_parameters() if name.startswith(POLICY_PREFIXES)}


@torch.no_grad()
def load_policy_weights(agent: torch.nn.Module, weights: dict[str, torch.Tensor]) -> None:
    """Copy ``weights`` (names of :func:`policy_parameters`) into the agent's parameters. Not
    through ``load_state_dict``: the agent's state dict also holds the same tensors under the
    names of the TorchRL wrappers, which would load the trained weights over them."""
    copy_into(policy_parameters(agent), weights)


@torch.no_grad()
def copy_into(params: dict[str, torch.Tensor], weights: dict[str, torch.Tensor]) -> None:
    """``params[name] <- weights[name]`` in place, for every name of ``weights``."""
    for name, tensor in weights.items():
        params[name].copy_(tensor)


class PolicyAverage:
    """Keeps ``average <- decay * average + (1 - decay) * weights`` after every iteration's PPO
    update (all its epochs and minibatches), not after each minibatch step.

    Args:
        agent: the :class:`~roto_trl.modules.agent.Agent` being trained.
        decay: in (0, 1): the weight of the old average per iteration; the average spans about
            ``1 / (1 - decay)`` iterations (0.95: 20).
    """

    def __init__(self, agent: torch.nn.Module, decay: float) -> None:
        self.decay = checked_decay(decay)
        if self.decay == 0.0:
            raise ValueError("PolicyAverage needs agent.policy_ema_decay > 0 (0 means no average)")
        self.params = policy_parameters(agent)
        self.average = {name: p.detach().clone() for name, p in self.params.items()}

    @torch.no_grad()
    def update(self) -> None:
        """Fold the current weights into the average (call after each PPO update)."""
        names = list(self.params)
        torch._foreach_lerp_(
            [self.average[n] for n in names], [self.params[n].detach() for n in names], 1.0 - self.decay
        )

    @contextmanager
    @torch.no_grad()
    def swapped_in(self) -> Iterator[None]:
        """The agent acts with the averaged weights inside the block; its own come back after."""
        current = {name: p.detach().clone() for name, p in self.params.items()}
        copy_into(self.params, self.average)
        try:
            yield
        finally:
            copy_into(self.params, current)

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {name: t.clone() for name, t in self.average.items()}

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> None:
        if set(state) != set(self.average):
            differ = sorted(set(state) ^ set(self.average))[:3]
            raise ValueError(
                f"the checkpoint's {POLICY_AVERAGE_KEY} does not fit this agent (names {differ} "
                "differ); resume with the run's own config"
            )
        copy_into(self.average, state)


def averaged(average: PolicyAverage | None) -> AbstractContextManager:
    """``average.swapped_in()``, or a context that changes nothing when there is no average."""
    return nullcontext() if average is None else average.swapped_in()
