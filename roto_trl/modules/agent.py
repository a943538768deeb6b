"""The actor-critic as TorchRL modules: a shared encoder writing ``"z"``, a policy and a value head.

    agent = Agent(obs_keys=("prop", "tactile"), obs_dim=..., n_actions=...)
    agent.policy       # obs -> z, loc, scale, action, action_log_prob   (acting, evaluation)
    agent.value        # obs -> z, state_value (normalised scale; see ``value_norm``)
    agent.actor_head   # z -> loc, scale, action, ...   (the PPO loss's actor)
    agent.critic_head  # z -> state_value               (the PPO loss's critic)

The losses read the latent from the minibatch (``agent.encode`` writes it, with gradients), so
the encoder runs once per minibatch and receives every loss's gradient through the same ``z``.
"""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictSequential
from torch import nn
from torchrl.modules import ActorValueOperator, ProbabilisticActor

from roto_trl.modules.distributions import ClippedActionNormal
from roto_trl.modules.networks import ENCODER_SIZES, Encoder, PolicyHead, ValueHead
from roto_trl.modules.normalization import ValueNormalizer
from roto_trl.modules.tensor_writes import TensorModule, TensorValueOperator

LATENT_KEY = "z"


def checked_critic_sizes(sizes, shared_encoder: bool) -> tuple[int, ...]:
    """``critic_encoder_sizes`` as a tuple (None: ``ENCODER_SIZES``), or a one-line error."""
    if sizes is None:
        return ENCODER_SIZES
    if shared_encoder:
        raise ValueError(
            "critic_encoder_sizes sizes the critic's own encoder: give it with shared_encoder=false, "
            "or leave it null"
        )
    if isinstance(sizes, int | str) or not len(sizes) or not all(type(s) is int and s > 0 for s in sizes):
        raise ValueError(
            f"critic_encoder_sizes must be a list of positive integers such as [256, 128], got {sizes!r}"
        )
    return tuple(sizes)


class Critic(nn.Module):
    """Observation parts -> normalised state value ``[*B, 1]``: an encoder and a value head."""

    def __init__(self, encoder: Encoder, head: ValueHead) -> None:
        super().__init__()
        self.encoder, self.head = encoder, head

    def forward(self, *parts: torch.Tensor) -> torch.Tensor:
        return self.head(self.encoder(*parts))


class Agent(nn.Module):
    """Everything a checkpoint holds of the agent: networks and the value normaliser.

    Args:
        obs_keys: observation entries the encoder reads, concatenated in this order.
        obs_dim: their total size (e.g. ``k * (P + T)``).
        n_actions: action size.
        shared_encoder: True (the paper): one encoder feeds the policy and the value head.
            False: the critic has its own encoder (``critic_encoder_sizes``), trained by the
            value loss only; the policy's encoder is the one the SSL objectives train (``common``).
        init_log_std: the policy's initial log standard deviation (0: std 1, the paper's).
        deterministic_action: the evaluation action, ``applied_mean`` (the mean of the clipped
            action the env applies) or ``gaussian_mean`` (skrl's, the authors'); see
            ``roto_trl.modules.distributions``.
        value_norm: True: the value head learns returns normalised by running statistics
            (``ValueNormalizer``, the authors' skrl setup); False: raw returns (rsl_rl's).
        critic_encoder_sizes: the layer sizes of the critic's own encoder (``shared_encoder``
            False only); None: the policy encoder's ``ENCODER_SIZES``. A smaller critic makes
            the update cheaper: at the default sizes the critic's encoder is nearly half of it.
        precision: the hidden layers' matrix products, ``float32`` or ``bfloat16`` (factors
            rounded to bfloat16, sums in float32; activations, weights, the optimiser and the
            output layers' forward stay float32); see ``roto_trl.modules.networks.hidden_precision``.
    """

    def __init__(
        self,
        obs_keys: tuple[str, ...],
        obs_dim: int,
        n_actions: int,
        shared_encoder: bool = True,
        init_log_std: float = 0.0,
        deterministic_action: str = "applied_mean",
        value_norm: bool = True,
        critic_encoder_sizes: tuple[int, ...] | None = None,
        precision: str = "float32",
    ) -> None:
        super().__init__()
        critic_encoder_sizes = checked_critic_sizes(critic_encoder_sizes, shared_encoder)
        self.obs_keys = tuple(obs_keys)
        self.n_actions = int(n_actions)
        self.encoder = Encoder(obs_dim, precision=precision)
        self.policy_head = PolicyHead(self.encoder.latent_dim, n_actions, init_log_std, precision)
        # the critic's own encoder is registered after the policy's modules, as before the option,
        # so that the optimiser's parameter order (and a resumed run's Adam state) is unchanged
        value_encoder = None if shared_encoder else Encoder(obs_dim, critic_encoder_sizes, precision)
        self.value_head = ValueHead((self.encoder if shared_encoder else value_encoder).latent_dim, precision)
        self.value_norm = ValueNormalizer(enabled=value_norm)
        # observation entries -> z: the encoder as the self-supervised losses take it
        self.common = TensorModule(self.encoder, in_keys=list(self.obs_keys), out_keys=[LATENT_KEY])
        self.actor_head = ProbabilisticActor(
            TensorModule(self.policy_head, in_keys=[LATENT_KEY], out_keys=["loc", "scale"]),
            in_keys=["loc", "scale"],
            distribution_class=ClippedActionNormal,
            distribution_kwargs={"deterministic_action": str(deterministic_action)},
            return_log_prob=True,
        )
        self.deterministic_action = deterministic_action
        self.shared_encoder = bool(shared_encoder)
        if self.shared_encoder:  # the paper's agent: the value head reads the policy's z
            self.critic_head = TensorValueOperator(self.value_head, in_keys=[LATENT_KEY])
            self.actor_critic = ActorValueOperator(self.common, self.actor_head, self.critic_head)
            self.policy = self.actor_critic.get_policy_operator()
            self.value = self.actor_critic.get_value_operator()
        else:  # the critic has an encoder of its own; SSL trains the policy's
            self.value_encoder = value_encoder
            self.critic_head = TensorValueOperator(
                Critic(self.value_encoder, self.value_head), in_keys=list(self.obs_keys)
            )
            self.policy = TensorDictSequential(self.common, self.actor_head)
            self.value = self.critic_head

    def encode(self, td):
        """Write the latent ``z`` ``[*B, 256]`` of ``td``'s observations into ``td`` (with gradients)."""
        td.set(LATENT_KEY, self.encoder(*(td.get(k) for k in self.obs_keys)))
        return td

    def normalised_value(self, td) -> torch.Tensor:
        """The value head's output ``[*B, 1]`` for ``td``, which holds the ``z`` the policy wrote
        while acting: the shared encoder's latent is reused, a separate critic encodes the
        observations itself."""
        if self.shared_encoder:
            return self.value_head(td.get(LATENT_KEY))
        return self.value_head(self.value_encoder(*(td.get(k) for k in self.obs_keys)))

    @torch.no_grad()
    def raw_value(self, td) -> torch.Tensor:
        """State value on the return scale ``[*B, 1]`` (the value head's output denormalised)."""
        return self.value_norm.denormalize(self.value(td.select(*self.obs_keys))["state_value"])
