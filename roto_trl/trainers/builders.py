"""Config -> objects, in one place: envs, agent, PPO loss, advantage, collector, buffer, optimiser,
learning-rate schedule and the self-supervised objective.

``cfg`` is the composed Hydra config of ``roto_trl/train.py`` (``conf/train.yaml``), or the plain
dict a checkpoint stores.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from omegaconf import DictConfig, OmegaConf
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers import SamplerWithoutReplacement
from torchrl.envs import TransformedEnv
from torchrl.objectives import ClipPPOLoss, LossModule
from torchrl.objectives.value import GAE

from roto_trl.data.memory import AuxMemory
from roto_trl.envs.factory import make_env
from roto_trl.modules.agent import Agent
from roto_trl.modules.distributions import DEFAULT_ACTION_LOG_PROB, DEFAULT_DETERMINISTIC_ACTION
from roto_trl.modules.networks import cpu_has_bfloat16, on_cpu, resolved_precision
from roto_trl.objectives import (
    ForwardDynamicsLoss,
    FullReconstructionLoss,
    PolicyMeanBoundLoss,
    ProximalFeatureLoss,
    TactileForwardDynamicsLoss,
    TactileReconstructionLoss,
)
from roto_trl.trainers.auxiliary import AuxiliaryUpdate
from roto_trl.trainers.lr_schedule import KLAdaptiveLR, LinearDecayLR
from roto_trl.trainers.policy_average import PolicyAverage, checked_decay, span_note
from roto_trl.trainers.schedule import frames_per_iteration
from roto_trl.trainers.std_ceiling import DEFAULT_FRAMES, StdCeiling, checked_std_ceiling
from roto_trl.utils.cli import is_number, non_negative_or_off, number_pair, positive_int_or_null

EVAL_SEED_OFFSET = 1_000_003  # evaluation worlds never share reset draws with training worlds


def _cfg(cfg) -> DictConfig:
    return cfg if isinstance(cfg, DictConfig) else OmegaConf.create(cfg)


def make_task_env(cfg, num_envs: int, seed: int) -> TransformedEnv:
    """The run's task with its overrides, ``num_envs`` worlds."""
    cfg = _cfg(cfg)
    overrides = OmegaConf.to_container(cfg.env.overrides, resolve=True)
    return make_env(
        cfg.env.task,
        int(num_envs),
        seed=int(seed),
        device=cfg.device,
        last_action=bool(cfg.env.last_action),
        **overrides,
    )


def make_train_env(cfg) -> TransformedEnv:
    cfg = _cfg(cfg)
    return make_task_env(cfg, cfg.env.num_envs, cfg.seed)


def make_eval_env(cfg, num_envs: int | None = None) -> TransformedEnv:
    """The evaluation env: its own worlds and seed, never part of the training data.

    ``num_envs`` (one episode each) defaults to ``eval.num_envs``.
    """
    cfg = _cfg(cfg)
    return make_task_env(
        cfg, cfg.eval.num_envs if num_envs is None else num_envs, cfg.seed + EVAL_SEED_OFFSET
    )


def eval_seed(cfg) -> int:
    """The seed of every evaluation of a run: the same episodes each time, so returns compare."""
    return int(_cfg(cfg).seed) + 1


def agent_for_env(cfg, env: TransformedEnv) -> Agent:
    """The agent whose encoder reads ``cfg.env.obs_keys`` of ``env``."""
    cfg = _cfg(cfg)
    keys = tuple(cfg.env.obs_keys)
    spec = env.observation_spec
    missing = [k for k in keys if k not in spec]
    if missing:
        raise ValueError(f"env.obs_keys {missing} are not observations of {cfg.env.task}; use prop/tactile")
    obs_dim = sum(int(spec[k].shape[-1]) for k in keys)
    shared = bool(cfg.agent.get("shared_encoder", True))  # runs from before the option: shared
    agent = Agent(
        keys,
        obs_dim,
        env.base_env.n_actions,
        shared_encoder=shared,
        init_log_std=float(cfg.agent.get("init_log_std", 0.0)),
        # runs from before the option: the default, which changes no parameter
        deterministic_action=str(cfg.agent.get("deterministic_action", DEFAULT_DETERMINISTIC_ACTION)),
        value_norm=bool(cfg.agent.get("value_norm", True)),  # runs from before the option: on
        critic_encoder_sizes=cfg.agent.get("critic_encoder_sizes"),  # null: the policy encoder's
        action_log_prob=str(cfg.agent.get("action_log_prob", DEFAULT_ACTION_LOG_PROB)),  # old runs: gaussian
        precision=agent_precision(cfg),
    )
    return agent.to(cfg.device)


# the agent's networks by attribute name; ``value_encoder`` exists only without the shared encoder
AGENT_PARTS = ("encoder", "policy_head", "value_head", "value_encoder")


def agent_parts(agent: Agent, names: Sequence[str] = AGENT_PARTS) -> list[torch.nn.Module]:
    """The agent's networks named in ``names`` that it has (``AGENT_PARTS``)."""
    return [getattr(agent, name) for name in names if hasattr(agent, name)]


def compile_on(cfg) -> bool:
    """``agent.compile``: ``torch.compile`` the agent's networks (``compile_agent``) and the PPO loss
    (``make_ppo_loss``); configs saved before the option: off."""
    return bool(_cfg(cfg).agent.get("compile", False))


def compile_agent(cfg, agent: Agent) -> None:
    """With ``agent.compile``, ``torch.compile`` the encoders and heads in place.

    ``Module.compile`` keeps parameter names, so checkpoints load into an uncompiled agent and back.
    Off by default: compiling takes 5-60 s on 2 cores (again for each new batch shape, then
    dynamic) and needs a C++ compiler, and it pays in float32 only. With the loss compiled too
    (``make_ppo_loss``) a float32 minibatch step of the recipe's ``bounce_ppo`` at 256 worlds took
    37.1 and 37.6 ms against 39.9 and 41.5 eager (medians of six alternated rounds, two runs; the
    networks alone 39.2 and 40.5, the loss alone 38.6 and 39.7); under bfloat16 products
    (``agent.precision``) 28.7 against 27.0 eager, slower. End to end ``train_throughput.py
    --compile`` did not resolve either difference from its noise (README, Throughput).
    """
    if compile_on(cfg):
        for module in agent_parts(agent):  # the critic's own encoder too, where it has one
            module.compile()


def make_ppo_loss(cfg, agent: Agent) -> ClipPPOLoss:
    """TorchRL's ``ClipPPOLoss`` with the paper's clipping and scales, over the heads.

    The actor and critic read ``z`` from the minibatch (``agent.encode``), so the shared encoder
    runs once per minibatch. The value head works on the normalised scale: the loop writes
    normalised ``value_target`` and ``state_value`` into the batch before the loss sees it.

    c_ent (``agent.entropy_coeff``) multiplies the Gaussian's entropy per action dimension (the
    mean over dimensions, skrl's convention, in which the paper's c_ent values were tuned);
    TorchRL's loss takes the entropy summed over dimensions, so its coefficient is c_ent / A.
    The logged ``entropy`` is TorchRL's, the sum. ``agent.clip_value: null`` trains the value head
    on the plain squared error (no ``value_clip_fraction`` is then logged). With ``agent.compile``
    its forward is ``torch.compile``d: its Python was about 8 % of a float32 minibatch step, and
    compiled alone it saved 3-4 % (``compile_agent``); the losses agree with the eager ones to
    float32 rounding.
    """
    a = _cfg(cfg).agent
    loss = ClipPPOLoss(
        actor_network=agent.actor_head,
        critic_network=agent.critic_head,
        clip_epsilon=float(a.clip_epsilon),
        clip_value=None if a.clip_value is None else float(a.clip_value),  # None: unclipped
        entropy_bonus=True,
        entropy_coeff=float(a.entropy_coeff) / agent.n_actions,
        critic_coeff=float(a.critic_coeff),
        loss_critic_type="l2",
        normalize_advantage=advantage_norm_scope(a.get("normalize_advantage")) == "minibatch",
        functional=False,  # the heads' own parameters: one optimiser updates them with the encoder
    )
    if compile_on(cfg):
        loss.compile()
    return loss


def make_mean_bound_loss(cfg, agent: Agent) -> PolicyMeanBoundLoss | None:
    """The bound on the policy mean's pre-tanh output (``agent.mean_bound``, weight
    ``agent.mean_bound_coeff``), or None when the weight is 0 (the default): then the update does
    no extra work (``mean_saturation`` comes from the rollout, ``ppo.rollout_stats``)."""
    a = _cfg(cfg).agent  # a run saved before these keys existed gets the defaults (None)
    loss = PolicyMeanBoundLoss(agent.policy_head, bound=a.get("mean_bound"), coeff=a.get("mean_bound_coeff"))
    return loss if loss.coeff > 0 else None


def make_proximal_feature_loss(cfg) -> ProximalFeatureLoss | None:
    """The penalty on how far an update moves the policy encoder's latent from the rollout's
    (``agent.proximal_feature_coeff`` > 0), or None (the default, 0: no extra work)."""
    loss = ProximalFeatureLoss(coeff=_cfg(cfg).agent.get("proximal_feature_coeff"))  # older runs: off
    return loss if loss.coeff > 0 else None


def make_policy_terms(cfg, agent: Agent) -> tuple[LossModule, ...]:
    """The optional terms each PPO minibatch's loss adds (``ppo.minibatch_loss``): the mean
    bound and the proximal feature penalty, those whose weight is > 0 (none by default)."""
    terms = (make_mean_bound_loss(cfg, agent), make_proximal_feature_loss(cfg))
    return tuple(term for term in terms if term is not None)


def make_policy_average(cfg, agent: Agent) -> PolicyAverage | None:
    """The moving average of the policy's weights that evaluations use (``agent.policy_ema_decay``
    > 0), or None (the default, 0: evaluations use the current weights)."""
    cfg = _cfg(cfg)
    decay = checked_decay(cfg.agent.get("policy_ema_decay"))  # older runs lack the key: off
    note = span_note(decay, int(cfg.total_frames) // frames_per_iteration(cfg))
    if note is not None:
        print(note)
    return PolicyAverage(agent, decay) if decay > 0 else None


def make_std_ceiling(cfg, agent: Agent, optimizer: torch.optim.Optimizer) -> StdCeiling | None:
    """The falling ceiling on the policy's standard deviation (``agent.std_ceiling`` > 0),
    projected after every step of ``optimizer``, or None (the default, null: no ceiling but the
    log-std clamp)."""
    cfg = _cfg(cfg)
    a = cfg.agent
    final, (begin, end) = checked_std_ceiling(
        a.get("std_ceiling"), a.get("std_ceiling_frames", DEFAULT_FRAMES), int(cfg.total_frames)
    )
    if final is None:  # older runs lack the keys: off
        return None
    start = math.exp(float(a.get("init_log_std", 0.0)))
    return StdCeiling(agent.policy_head.log_std, start, final, begin, end).attach(optimizer)


ADVANTAGE_NORM_SCOPES = ("minibatch", "batch", "none")


def advantage_norm_scope(value) -> str:
    """``agent.normalize_advantage`` as one of ``ADVANTAGE_NORM_SCOPES``.

    ``minibatch`` (the default): each PPO minibatch's advantages are standardised in the loss;
    ``batch``: the whole rollout's, once after GAE (rsl_rl's and skrl's default); ``none``: raw.
    Configs saved before the scopes existed hold a bool: true is ``minibatch``, false ``none``.
    """
    if value is None or value is True:
        return "minibatch"
    if value is False:
        return "none"
    if value not in ADVANTAGE_NORM_SCOPES:
        choices = list(ADVANTAGE_NORM_SCOPES)
        raise ValueError(f"agent.normalize_advantage must be one of {choices}, got {value!r}")
    return str(value)


def make_advantage(cfg) -> GAE:
    """GAE over the ``state_value`` entries the loop writes (no value network of its own).

    ``("next", "terminated")`` stops bootstrapping; a time-limit truncation (``done`` without
    ``terminated``) bootstraps from the value of the episode's last observation. With
    ``agent.normalize_advantage=batch`` the rollout's advantages [N, R] are standardised here
    (the value targets stay the unstandardised advantage + value).
    """
    a = _cfg(cfg).agent
    whole_batch = advantage_norm_scope(a.get("normalize_advantage")) == "batch"
    return GAE(gamma=float(a.gamma), lmbda=float(a.lmbda), value_network=None, average_gae=whole_batch)


def apply_rollout_floor(cfg) -> None:
    """Raise ``agent.rollout_len`` to ``agent.min_rollout_len`` where it is shorter (edits ``cfg``).

    The CPU profile's floor of 32 steps: at its 256 worlds the paper's 16-step rollouts of
    ``bounce_ppo`` (tuned for 4096 worlds, 4,096 frames per update here) learned and fell back
    (final policies 21.8 bounces per 10 s, 3 seeds); 32 steps ended at 33.5 over 9 seeds, 5 of
    them holding (README, "Results on a CPU"). Exps with R >= 32 keep theirs. Says so in one line
    when it changes R.
    None (the default, and configs saved before the option) leaves R as it is.
    """
    a = _cfg(cfg).agent
    floor = positive_int_or_null("agent.min_rollout_len", a.get("min_rollout_len"), "no floor")
    if floor is not None and a.rollout_len < floor:
        print(
            f"agent.rollout_len: {a.rollout_len} -> {floor} (agent.min_rollout_len; "
            f"agent.min_rollout_len=null keeps {a.rollout_len})"
        )
        a.rollout_len = floor


def agent_precision(cfg) -> str:
    """``agent.precision`` resolved for this machine (``resolved_precision``); configs saved before
    the option: float32."""
    cfg = _cfg(cfg)
    return resolved_precision(str(cfg.agent.get("precision", "float32")), str(cfg.device))


def apply_precision(cfg) -> None:
    """Replace ``agent.precision=auto`` by what it resolves to on this machine (edits ``cfg``, so
    that the run's saved config holds it) and say so in one line."""
    a = _cfg(cfg).agent
    if a.get("precision") == "auto":
        a.precision = agent_precision(cfg)
        if not on_cpu(cfg.device):
            why = "bfloat16 products are a CPU path"
        else:
            why = f"a CPU {'with' if cpu_has_bfloat16() else 'without'} bfloat16 products in hardware"
        print(f"agent.precision: auto -> {a.precision} (device={cfg.device}: {why})")


def gae_horizon(cfg) -> int | None:
    """``agent.gae_horizon``: steps after which GAE's trace is cut (``store_rollout``), or None.

    None (the default, and configs saved before the option) cuts only at the rollout's end.
    """
    return positive_int_or_null("agent.gae_horizon", _cfg(cfg).agent.get("gae_horizon"), "the rollout")


def make_collector(cfg, env: TransformedEnv, agent: Agent) -> Collector:
    """Rollouts of ``rollout_len`` steps of every training world, ``[num_envs, rollout_len]``."""
    cfg = _cfg(cfg)
    return Collector(
        env,
        agent.policy,
        frames_per_batch=frames_per_iteration(cfg),
        total_frames=-1,
        device=cfg.device,
        auto_register_policy_transforms=False,  # the policy needs no transform the env lacks
    )


def make_rollout_buffer(cfg) -> TensorDictReplayBuffer:
    """The on-policy buffer: one rollout, sampled in ``minibatches`` disjoint minibatches per epoch."""
    cfg = _cfg(cfg)
    frames = frames_per_iteration(cfg)
    return TensorDictReplayBuffer(
        storage=LazyTensorStorage(frames, device=cfg.device),
        sampler=SamplerWithoutReplacement(),
        batch_size=frames // int(cfg.agent.minibatches),
    )


ADAM_BETAS = (0.9, 0.999)  # torch's (and skrl's, rsl_rl's) defaults


def adam_betas(value) -> tuple[float, float]:
    """``agent.adam_betas`` as Adam's ``(beta1, beta2)``, each in [0, 1), or a one-line error."""
    pair = number_pair(value)
    if pair is None or not all(0.0 <= float(b) < 1.0 for b in pair):
        raise ValueError(
            f"agent.adam_betas must be [beta1, beta2] with each in [0, 1), e.g. [0.9,0.999], got {value!r}"
        )
    return float(pair[0]), float(pair[1])


ADAM_EPS = 1e-8  # torch's (and rsl_rl's); CleanRL and OpenAI Baselines' PPO use 1e-5


def adam_eps(value) -> float:
    """``agent.adam_eps`` as Adam's denominator term, a number > 0, or a one-line error."""
    if not (is_number(value) and value > 0):
        raise ValueError(f"agent.adam_eps must be a number > 0, e.g. 1e-5, got {value!r}")
    return float(value)


def weight_decay(value) -> float:
    """``agent.weight_decay`` as a float >= 0 (None: 0, off), or a one-line error naming the fix."""
    return non_negative_or_off("agent.weight_decay", value, example="1.0")


DECAYABLE_PARTS = AGENT_PARTS  # every network's weight matrices may decay


def weight_decay_parts(value) -> tuple[str, ...]:
    """``agent.weight_decay_parts``: the agent's parts whose weight matrices decay (None: all of
    ``DECAYABLE_PARTS``), or a one-line error naming the fix."""
    if value is None:
        return DECAYABLE_PARTS
    parts = tuple(value) if isinstance(value, Sequence) and not isinstance(value, str) else ()
    if not parts or any(part not in DECAYABLE_PARTS for part in parts):
        raise ValueError(
            f"agent.weight_decay_parts must be a non-empty list of {', '.join(DECAYABLE_PARTS)} "
            f"(null: all), e.g. [policy_head], got {value!r}"
        )
    return parts


def log_std_lr(a) -> float | None:
    """The fixed rate of the policy's log-std in a parameter group of its own, outside the KL
    rule: ``agent.log_std_lr`` when set (a number > 0), ``agent.lr`` with
    ``agent.log_std_fixed_lr=true``, else None (the log-std moves with the networks). A bad
    value is a one-line error naming the fix."""
    value = a.get("log_std_lr")  # older runs lack the key: null
    if value is not None:
        if not (is_number(value) and value > 0):
            raise ValueError(
                f"agent.log_std_lr must be a number > 0 or null (the networks' rate), got {value!r}"
            )
        return float(value)
    return float(a.lr) if bool(a.get("log_std_fixed_lr", False)) else None


def make_optimizer(cfg, agent: Agent) -> torch.optim.Optimizer:
    """The PPO optimiser: one Adam over encoder + policy + value (the SSL gradient reaches the
    encoder through the same backward, see ``roto_trl.trainers.auxiliary``).

    ``agent.fused_adam`` (default true) uses PyTorch's fused Adam, one kernel over all parameters:
    on the CPU its step took 3.5-4 ms against 9-13 ms for the default per-parameter loop
    (``benchmarks/train_throughput.py --fused``); same maths, rounding aside.

    ``agent.log_std_fixed_lr`` (default false) puts the policy's log-std in a parameter group of
    its own that keeps ``agent.lr`` when ``agent.lr_schedule=kl_adaptive`` moves the others' rate
    (``kl_adaptive: False`` in the group), so that the standard deviation can shrink at the
    paper's rate while the KL rule holds the networks' steps at a tenth of it;
    ``agent.log_std_lr`` (default null) gives that group a rate of its own instead (Adam moves a
    parameter by at most about its rate per step, so at the KL rule's 0.3-6e-5 the log-std can
    move by only 0.1-0.2 in a 2 M-frame run on Find: the standard deviation stays near its
    initial 1; README "Left to do").
    Each group records its starting rate as ``base_lr``, which the annealed fixed rate follows.

    ``agent.adam_betas`` (default torch's ``[0.9, 0.999]``) are Adam's moment decays; equal betas
    (e.g. ``[0.99, 0.99]``) are Dohare et al.'s (2023, "Overcoming policy collapse in deep RL")
    remedy for PPO's collapse in long runs: with beta2 > beta1 the second moment lags the first,
    and a gradient that grows after a quiet stretch takes outsized steps. ``agent.adam_eps``
    (default torch's 1e-8) is the term added to the second moment's root: a parameter whose
    gradient's root mean square is near or under it steps less than the learning rate, so a
    larger eps (CleanRL's 1e-5) damps the steps of parameters whose gradient has gone quiet.

    ``agent.weight_decay`` (default 0, off) > 0 makes it AdamW: after each step every weight
    matrix (not the biases, LayerNorm gains or the log-std) shrinks by ``lr * weight_decay`` of
    itself, against the weights' growth over a run; ``agent.weight_decay_parts`` (default null:
    all) limits it to some of the agent's parts (e.g. ``[policy_head]``; with the shared encoder
    there is no ``value_encoder``). The decay is scaled by the learning rate,
    which the KL rule holds at a few 1e-5 on Bounce, so useful values are 1-3 (measured there),
    not the usual 0.01. On Find both 1 and 3 lowered the final policies, so ``+profile=cpu``
    takes it from the task (``env.cpu_recipe.weight_decay``: 3.0 on Bounce, off on Find and
    Baoding; README "Results on a CPU"). The matrices come first, in a group of their own, the
    other parameters after.
    """
    a = _cfg(cfg).agent
    lr, fused = float(a.lr), bool(a.get("fused_adam", True))
    betas = adam_betas(a.get("adam_betas", ADAM_BETAS))  # older runs lack the key: torch's
    eps = adam_eps(a.get("adam_eps", ADAM_EPS))  # older runs lack the key: torch's
    decay = weight_decay(a.get("weight_decay"))  # older runs lack the key: off
    fixed_log_std = log_std_lr(a)
    if decay == 0.0 and fixed_log_std is None:
        return torch.optim.Adam(agent.parameters(), lr=lr, betas=betas, eps=eps, fused=fused)
    log_std = agent.policy_head.log_std
    networks = [p for p in agent.parameters() if p is not log_std]
    groups = [{"params": networks}]  # without decay one group, as checkpoints from before it hold
    if decay > 0.0:
        parts = weight_decay_parts(a.get("weight_decay_parts"))  # older runs lack the key: all
        decayed = {id(p) for part in agent_parts(agent, parts) for p in part.parameters() if p.dim() >= 2}
        groups = [
            {"params": [p for p in networks if id(p) in decayed], "weight_decay": decay},
            {"params": [p for p in networks if id(p) not in decayed], "weight_decay": 0.0},
        ]
    if fixed_log_std is None:
        groups[-1]["params"].append(log_std)
    else:
        groups.append({"params": [log_std], "lr": fixed_log_std, "kl_adaptive": False, "weight_decay": 0.0})
    for group in groups:
        group["base_lr"] = group.get("lr", lr)
    adam = torch.optim.AdamW if decay > 0.0 else torch.optim.Adam
    return adam(groups, lr=lr, betas=betas, eps=eps, fused=fused)


LR_SCHEDULES = ("fixed", "kl_adaptive")


def make_lr_schedule(cfg, optimizer: torch.optim.Optimizer) -> KLAdaptiveLR | LinearDecayLR | None:
    """``agent.lr_schedule``: the KL-adaptive rate (``agent.kl_target``) for ``kl_adaptive``; for
    ``fixed`` None (``agent.lr`` throughout), or with ``agent.anneal_step_size`` the rate's
    linear decay to zero over ``total_frames``."""
    a = _cfg(cfg).agent
    schedule = a.get("lr_schedule", "fixed")  # configs saved before the option existed: fixed
    if schedule not in LR_SCHEDULES:
        raise ValueError(f"agent.lr_schedule must be one of {list(LR_SCHEDULES)}, got {schedule!r}")
    anneal = bool(a.get("anneal_step_size", False))  # older runs lack the key: off
    if schedule == "kl_adaptive":
        return KLAdaptiveLR(optimizer, float(a.kl_target), anneal=anneal)
    return LinearDecayLR(optimizer, float(a.lr)) if anneal else None


SSL_OBJECTIVES = ("none", "tr", "fr", "fd", "tfd")


def make_aux_update(cfg, agent: Agent, env: TransformedEnv) -> AuxiliaryUpdate | None:
    """The configured self-supervised objective (``cfg.ssl``) with its optimiser and memory, or None.

    The memory keeps the actions the env applied: the policy's samples clipped to the env's
    action bounds.
    """
    cfg = _cfg(cfg)
    ssl = cfg.ssl
    if ssl.name not in SSL_OBJECTIVES:
        raise ValueError(f"ssl.name must be one of {list(SSL_OBJECTIVES)}, got {ssl.name!r}")
    if ssl.name == "none":
        return None
    spec = env.observation_spec
    needs_tactile = ssl.name in ("tr", "fr", "tfd")
    if needs_tactile and "tactile" not in spec:
        raise ValueError(f"ssl={ssl.name} reconstructs contacts but the env has no tactile observation")
    tactile_dim = int(spec["tactile"].shape[-1]) if "tactile" in spec else 0
    prop_dim = int(spec["prop"].shape[-1])
    n_actions = env.base_env.n_actions
    pos_weight = ssl.pos_weight if ssl.pos_weight == "auto" else float(ssl.pos_weight)
    encoder = agent.common
    if ssl.name == "tr":
        loss = TactileReconstructionLoss(encoder, tactile_dim, pos_weight=pos_weight)
    elif ssl.name == "fr":
        loss = FullReconstructionLoss(encoder, prop_dim, tactile_dim, pos_weight=pos_weight)
    elif ssl.name == "fd":
        loss = ForwardDynamicsLoss(encoder, n_actions)
    else:
        loss = TactileForwardDynamicsLoss(encoder, n_actions, tactile_dim, pos_weight=pos_weight)
    keys = tuple(dict.fromkeys([*agent.obs_keys, "prop", *(["tactile"] if tactile_dim else [])]))
    bounds = env.action_spec.space
    action_bounds = (bounds.low.reshape(-1, n_actions)[0], bounds.high.reshape(-1, n_actions)[0])
    memory = AuxMemory(int(ssl.memory_rollouts), keys, device=cfg.device, action_bounds=action_bounds)
    return AuxiliaryUpdate(
        loss.to(cfg.device),
        memory,
        lr=float(ssl.lr),
        coeff=float(ssl.coeff),
        seq_len=int(ssl.get("seq_len", 1)),
        tau=float(ssl.get("tau", 0.01)),
        fused=bool(cfg.agent.get("fused_adam", True)),
    )
