"""Config -> objects, in one place: envs, agent, PPO loss, advantage, collector, buffer, optimiser,
learning-rate schedule, the self-supervised objective and the update that holds
them.

``cfg`` is a typed training config (``roto_trl.config.typed_config``; a saved run's through
``roto_trl.config.run_config``), so every key is present with its type.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from omegaconf import DictConfig, OmegaConf
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers import SamplerWithoutReplacement
from torchrl.envs import TransformedEnv
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from roto_trl.config import AdvantageNorm, LrSchedule, SslName
from roto_trl.data.memory import AuxMemory
from roto_trl.envs.factory import make_env
from roto_trl.modules.agent import Agent
from roto_trl.modules.networks import resolved_precision
from roto_trl.objectives import (
    ForwardDynamicsLoss,
    FullReconstructionLoss,
    TactileForwardDynamicsLoss,
    TactileReconstructionLoss,
)
from roto_trl.trainers.auxiliary import AuxiliaryUpdate
from roto_trl.trainers.lr_schedule import KLAdaptiveLR
from roto_trl.trainers.ppo import PPOUpdate
from roto_trl.trainers.schedule import frames_per_iteration

EVAL_SEED_OFFSET = 1_000_003  # evaluation worlds never share reset draws with training worlds


def make_task_env(cfg: DictConfig, num_envs: int, seed: int) -> TransformedEnv:
    """The run's task with its overrides, ``num_envs`` worlds."""
    return make_env(
        str(cfg.env.task),
        int(num_envs),
        seed=int(seed),
        device=cfg.device,
        last_action=cfg.env.last_action,
        **OmegaConf.to_container(cfg.env.overrides, resolve=True),
    )


def make_train_env(cfg: DictConfig) -> TransformedEnv:
    return make_task_env(cfg, cfg.env.num_envs, cfg.seed)


def make_eval_env(cfg: DictConfig, num_envs: int | None = None) -> TransformedEnv:
    """The evaluation env: its own worlds and seed, never part of the training data.

    ``num_envs`` (one episode each) defaults to ``eval.num_envs``.
    """
    return make_task_env(
        cfg, cfg.eval.num_envs if num_envs is None else num_envs, cfg.seed + EVAL_SEED_OFFSET
    )


def eval_seed(cfg: DictConfig) -> int:
    """The seed of every evaluation of a run: the same episodes each time, so returns compare."""
    return int(cfg.seed) + 1


def agent_for_env(cfg: DictConfig, env: TransformedEnv) -> Agent:
    """The agent whose encoder reads ``cfg.env.obs_keys`` of ``env``."""
    keys = tuple(cfg.env.obs_keys)
    spec = env.observation_spec
    missing = [k for k in keys if k not in spec]
    if missing:
        raise ValueError(f"env.obs_keys {missing} are not observations of {cfg.env.task}; use prop/tactile")
    a = cfg.agent
    agent = Agent(
        keys,
        sum(int(spec[k].shape[-1]) for k in keys),
        env.base_env.n_actions,
        shared_encoder=a.shared_encoder,
        init_log_std=a.init_log_std,
        deterministic_action=str(a.deterministic_action),
        value_norm=a.value_norm,
        critic_encoder_sizes=a.critic_encoder_sizes,
        precision=resolved_precision(str(a.precision), cfg.device),  # a run has settled auto already
    )
    return agent.to(cfg.device)


# the agent's networks by attribute name; ``value_encoder`` exists only without the shared encoder
AGENT_PARTS = ("encoder", "policy_head", "value_head", "value_encoder")


def agent_parts(agent: Agent, names: Sequence[str] = AGENT_PARTS) -> list[torch.nn.Module]:
    """The agent's networks named in ``names`` that it has (``AGENT_PARTS``)."""
    return [getattr(agent, name) for name in names if hasattr(agent, name)]


def compile_agent(cfg: DictConfig, agent: Agent) -> None:
    """With ``agent.compile``, ``torch.compile`` the encoders and heads in place.

    ``Module.compile`` keeps parameter names, so checkpoints load into an uncompiled agent and back.
    Off by default: compiling takes seconds to a minute on 2 cores (again for each new batch
    shape) and needs a C++ compiler; what it saves: docs/throughput.md.
    """
    if cfg.agent.compile:
        for module in agent_parts(agent):  # the critic's own encoder too, where it has one
            module.compile()


def make_ppo_loss(cfg: DictConfig, agent: Agent) -> ClipPPOLoss:
    """TorchRL's ``ClipPPOLoss`` with the paper's clipping and scales, over the heads.

    The actor and critic read ``z`` from the minibatch (``agent.encode``), so the shared encoder
    runs once per minibatch. The value head works on the normalised scale: the update writes
    normalised ``value_target`` and ``state_value`` into the batch before the loss sees it.

    c_ent (``agent.entropy_coeff``) multiplies the Gaussian's entropy per action dimension (the
    mean over dimensions, skrl's convention, in which the paper's c_ent values were tuned);
    TorchRL's loss takes the entropy summed over dimensions, so its coefficient is c_ent / A.
    The logged ``entropy`` is TorchRL's, the sum. ``agent.clip_value: null`` trains the value head
    on the plain squared error. With ``agent.compile`` its forward is ``torch.compile``d too.
    """
    a = cfg.agent
    loss = ClipPPOLoss(
        actor_network=agent.actor_head,
        critic_network=agent.critic_head,
        clip_epsilon=a.clip_epsilon,
        clip_value=a.clip_value,  # None: unclipped
        entropy_bonus=True,
        entropy_coeff=a.entropy_coeff / agent.n_actions,
        critic_coeff=a.critic_coeff,
        loss_critic_type="l2",
        normalize_advantage=a.normalize_advantage == AdvantageNorm.minibatch,
        functional=False,  # the heads' own parameters: one optimiser updates them with the encoder
    )
    if a.compile:
        loss.compile()
    return loss


def make_advantage(cfg: DictConfig) -> GAE:
    """GAE over the ``state_value`` entries the update writes (no value network of its own).

    ``("next", "terminated")`` stops bootstrapping; a time-limit truncation (``done`` without
    ``terminated``) bootstraps from the value of the episode's last observation. With
    ``agent.normalize_advantage=batch`` the rollout's advantages [N, R] are standardised here
    (the value targets stay the unstandardised advantage + value).
    """
    a = cfg.agent
    whole_batch = a.normalize_advantage == AdvantageNorm.batch
    return GAE(gamma=a.gamma, lmbda=a.lmbda, value_network=None, average_gae=whole_batch)


def make_collector(cfg: DictConfig, env: TransformedEnv, agent: Agent) -> Collector:
    """Rollouts of ``rollout_len`` steps of every training world, ``[num_envs, rollout_len]``."""
    return Collector(
        env,
        agent.policy,
        frames_per_batch=frames_per_iteration(cfg),
        total_frames=-1,
        device=cfg.device,
        auto_register_policy_transforms=False,  # the policy needs no transform the env lacks
    )


def make_rollout_buffer(cfg: DictConfig) -> TensorDictReplayBuffer:
    """The on-policy buffer: one rollout, sampled in ``minibatches`` disjoint minibatches per epoch."""
    frames = frames_per_iteration(cfg)
    return TensorDictReplayBuffer(
        storage=LazyTensorStorage(frames, device=cfg.device),
        sampler=SamplerWithoutReplacement(),
        batch_size=frames // cfg.agent.minibatches,
    )


def make_optimizer(cfg: DictConfig, agent: Agent) -> torch.optim.Optimizer:
    """The PPO optimiser: one fused Adam over encoder + policy + value (the SSL gradient reaches the
    encoder through the same backward, see ``roto_trl.trainers.auxiliary``).

    Adam's eps is torch's 1e-8 (CleanRL's 1e-5 lost its ablation, docs/ablations.md).
    ``agent.weight_decay`` > 0 makes it AdamW: after each step every weight matrix (not the
    biases, LayerNorm gains or the log-std) shrinks by ``lr * weight_decay`` of itself; the
    matrices come first, in a group of their own. The decay is scaled by the learning rate,
    which the KL rule holds at a few 1e-5, so useful values are 1-3, not the usual 0.01
    (docs/recipe.md).
    """
    a = cfg.agent
    if a.weight_decay == 0.0:
        return torch.optim.Adam(agent.parameters(), lr=a.lr, fused=True)
    matrices = {id(p) for part in agent_parts(agent) for p in part.parameters() if p.dim() >= 2}
    log_std = agent.policy_head.log_std  # last, where the checkpoints' optimiser states hold it
    params = [p for p in agent.parameters() if p is not log_std]
    groups = [
        {"params": [p for p in params if id(p) in matrices], "weight_decay": a.weight_decay},
        {"params": [p for p in params if id(p) not in matrices] + [log_std], "weight_decay": 0.0},
    ]
    return torch.optim.AdamW(groups, lr=a.lr, fused=True)


def make_lr_schedule(cfg: DictConfig, optimizer: torch.optim.Optimizer) -> KLAdaptiveLR | None:
    """``agent.lr_schedule``: the KL-adaptive rate (``agent.kl_target``), or None for ``fixed``."""
    if cfg.agent.lr_schedule == LrSchedule.kl_adaptive:
        return KLAdaptiveLR(optimizer, cfg.agent.kl_target)
    return None


def make_aux_update(cfg: DictConfig, agent: Agent, env: TransformedEnv) -> AuxiliaryUpdate | None:
    """The configured self-supervised objective (``cfg.ssl``) with its optimiser and memory, or None.

    The memory keeps the actions the env applied: the policy's samples clipped to the env's
    action bounds.
    """
    ssl = cfg.ssl
    if ssl.name == SslName.none:
        return None
    spec = env.observation_spec
    needs_tactile = ssl.name in (SslName.tr, SslName.fr, SslName.tfd)
    if needs_tactile and "tactile" not in spec:
        raise ValueError(f"ssl={ssl.name} reconstructs contacts but the env has no tactile observation")
    tactile_dim = int(spec["tactile"].shape[-1]) if "tactile" in spec else 0
    n_actions = env.base_env.n_actions
    pos_weight = ssl.pos_weight if ssl.pos_weight == "auto" else float(ssl.pos_weight)
    encoder = agent.common
    if ssl.name == SslName.tr:
        loss = TactileReconstructionLoss(encoder, tactile_dim, pos_weight=pos_weight)
    elif ssl.name == SslName.fr:
        loss = FullReconstructionLoss(
            encoder, int(spec["prop"].shape[-1]), tactile_dim, pos_weight=pos_weight
        )
    elif ssl.name == SslName.fd:
        loss = ForwardDynamicsLoss(encoder, n_actions)
    else:
        loss = TactileForwardDynamicsLoss(encoder, n_actions, tactile_dim, pos_weight=pos_weight)
    keys = tuple(dict.fromkeys([*agent.obs_keys, "prop", *(["tactile"] if tactile_dim else [])]))
    bounds = env.action_spec.space
    action_bounds = (bounds.low.reshape(-1, n_actions)[0], bounds.high.reshape(-1, n_actions)[0])
    memory = AuxMemory(ssl.memory_rollouts, keys, device=cfg.device, action_bounds=action_bounds)
    return AuxiliaryUpdate(
        loss.to(cfg.device), memory, lr=ssl.lr, coeff=ssl.coeff, seq_len=ssl.seq_len, tau=ssl.tau
    )


def make_update(cfg: DictConfig, agent: Agent, env: TransformedEnv) -> PPOUpdate:
    """The whole update of an iteration (``PPOUpdate``): PPO loss, advantage, optimiser, schedules,
    the self-supervised objective and the rollout buffer, for ``agent`` trained on ``env``."""
    compile_agent(cfg, agent)  # agent.compile=true only
    optimizer = make_optimizer(cfg, agent)
    return PPOUpdate(
        agent,
        make_ppo_loss(cfg, agent),
        make_advantage(cfg),
        optimizer,
        make_rollout_buffer(cfg),
        epochs=cfg.agent.epochs,
        minibatches=cfg.agent.minibatches,
        max_grad_norm=cfg.agent.max_grad_norm,
        lr_schedule=make_lr_schedule(cfg, optimizer),
        aux=make_aux_update(cfg, agent, env),
    )
