"""The training config's schema: every key of ``conf/train.yaml`` with its type, choices and range.

The dataclasses below are registered in Hydra's ``ConfigStore`` (``schema/train``) and are the one
place where a key is declared. ``conf/`` supplies the values; :func:`typed_config` merges a
composed (or saved) config into the schema, so that

- a misspelt key, even one added with ``+`` (``+agent.lrr=1e-3``), is an error, not a silent no-op;
- a value of the wrong type, outside its choices or its range is a one-line ``ValueError`` naming
  the key and the fix (``train.py`` exits with status 2), where Hydra's own schema errors would be
  several lines and status 1: that is why ``train.py`` merges here rather than listing the schema
  in ``conf/train.yaml``'s defaults;
- a run saved before a key existed loads with the key's default (:func:`run_config`), so that
  nothing that reads a config needs a fallback of its own;
- a run saved with an option that has since been retired (``RETIRED``) is refused in one line
  naming the option and the git tag that still has it (``docs/ablations.md``).

``conf/agent/ppo.yaml`` and ``docs/keys.md`` say what each key does.
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields, is_dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any, get_type_hints

import torch
from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import ConfigKeyError, OmegaConfBaseException, ValidationError

from roto_trl.modules.networks import cpu_has_bfloat16, on_cpu, resolved_precision
from roto_trl.utils.cli import frame_count

RETIRED_TAG = "ablations-2026-12"  # the last commit that has the retired options (docs/ablations.md)


class Choice(StrEnum):
    """A config value from a fixed set; compares equal to its string."""


class Precision(Choice):
    float32 = "float32"
    bfloat16 = "bfloat16"
    auto = "auto"  # bfloat16 where the CPU multiplies it in hardware, else float32


class LrSchedule(Choice):
    fixed = "fixed"
    kl_adaptive = "kl_adaptive"


class AdvantageNorm(Choice):
    minibatch = "minibatch"
    batch = "batch"
    none = "none"


class DeterministicAction(Choice):
    applied_mean = "applied_mean"
    gaussian_mean = "gaussian_mean"


class SslName(Choice):
    none = "none"
    tr = "tr"
    fr = "fr"
    fd = "fd"
    tfd = "tfd"


class LoggerBackend(Choice):
    csv = "csv"
    none = "none"
    tensorboard = "tensorboard"
    wandb = "wandb"


class Task(Choice):
    find = "find"
    bounce = "bounce"
    baoding = "baoding"


def _range(default: Any, **bounds: float) -> Any:
    """A dataclass field with ``default`` and bounds (``gt``, ``ge``, ``lt``, ``le``) that
    :func:`check_ranges` enforces."""
    return field(default=default, metadata=bounds)


@dataclass
class AgentConfig:
    """PPO and the agent's networks (``conf/agent/ppo.yaml``)."""

    shared_encoder: bool = True
    critic_encoder_sizes: list[int] | None = None
    rollout_len: int = _range(32, ge=1)
    min_rollout_len: int | None = _range(None, ge=1)
    minibatches: int = _range(16, ge=1)
    epochs: int = _range(8, ge=1)
    lr: float = _range(1.0e-4, gt=0)
    entropy_coeff: float = _range(0.0, ge=0)
    gamma: float = _range(0.99, ge=0, le=1)
    lmbda: float = _range(0.95, ge=0, le=1)
    critic_coeff: float = _range(0.1, ge=0)
    init_log_std: float = _range(0.0, ge=-20, le=2)
    deterministic_action: DeterministicAction = DeterministicAction.applied_mean
    clip_epsilon: float = _range(0.2, gt=0)
    clip_value: float | None = _range(0.2, gt=0)
    max_grad_norm: float = _range(1.0, gt=0)
    normalize_advantage: AdvantageNorm = AdvantageNorm.minibatch
    value_norm: bool = True
    lr_schedule: LrSchedule = LrSchedule.fixed
    kl_target: float = _range(0.008, gt=0)
    weight_decay: float = _range(0.0, ge=0)
    precision: Precision = Precision.float32
    compile: bool = False


@dataclass
class SslConfig:
    """The self-supervised objective (``conf/ssl/``); keys an objective does not use are ignored."""

    name: SslName = SslName.none
    lr: float = _range(1.0e-4, gt=0)
    coeff: float = _range(0.01, ge=0)
    pos_weight: Any = 10  # a number > 0, or "auto" (checked in check_config)
    seq_len: int = _range(2, ge=2)
    tau: float = _range(0.01, gt=0, le=1)
    memory_rollouts: int = _range(1, ge=1)


@dataclass
class EnvConfig:
    """The task and its worlds (``conf/env/``)."""

    task: Task = Task.find
    num_envs: int = _range(4096, ge=1)
    budget_frames: int = _range(200_000_000, ge=1)
    obs_keys: list[str] = field(default_factory=lambda: ["prop", "tactile"])
    last_action: bool = True
    overrides: dict[str, Any] = field(default_factory=dict)


@dataclass
class EvalConfig:
    num_envs: int = _range(100, ge=1)
    every_frames: int = _range(2_000_000, ge=1)


@dataclass
class CheckpointConfig:
    interval_minutes: float = _range(10.0, ge=0)


@dataclass
class LoggerConfig:
    backend: LoggerBackend = LoggerBackend.wandb
    project: str = "roto-trl"
    aux_minibatches: bool = False


@dataclass
class DivergenceConfig:
    """When a run counts as diverging (``roto_trl.trainers.divergence``)."""

    grad_norm: float = _range(1000.0, gt=0)
    loss: float = _range(10000.0, gt=0)
    stop_after: int | None = _range(5, ge=1)


@dataclass
class TrainConfig:
    """Everything ``roto_trl/train.py`` reads (``conf/train.yaml``)."""

    env: EnvConfig = field(default_factory=EnvConfig)
    agent: AgentConfig = field(default_factory=AgentConfig)
    ssl: SslConfig = field(default_factory=SslConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    exp_name: str = "find_ppo"
    seed: int = _range(0, ge=0)
    device: str = "cpu"
    total_frames: int = _range(200_000_000, ge=1)
    time_limit_minutes: float | None = _range(None, gt=0)
    resume: str | None = None
    run_dir: str | None = None
    torch_threads: int | None = _range(None, ge=1)
    eval: EvalConfig = field(default_factory=EvalConfig)
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)
    divergence: DivergenceConfig = field(default_factory=DivergenceConfig)
    progress: bool = True


ConfigStore.instance().store(group="schema", name="train", node=TrainConfig)


def schema() -> DictConfig:
    """The schema as a structured config: every key at its default, typed (``TrainConfig``)."""
    return OmegaConf.structured(ConfigStore.instance().load("schema/train.yaml").node)


# -- options retired after their ablations lost: key -> whether a saved value changes nothing


def _always(_value, _cfg) -> bool:
    return True


def _equals(off) -> Callable[[Any, Mapping], bool]:
    return lambda value, _cfg: value == off


RETIRED: dict[str, Callable[[Any, Mapping], bool]] = {
    "agent.gae_horizon": _equals(None),
    "agent.action_log_prob": _equals("gaussian"),
    "agent.mean_bound": _always,  # only the coefficient switched it on
    "agent.mean_bound_coeff": _equals(0.0),
    "agent.proximal_feature_coeff": _equals(0.0),
    "agent.policy_ema_decay": _equals(0.0),
    "agent.log_std_fixed_lr": _equals(False),
    "agent.log_std_lr": _equals(None),
    "agent.anneal_step_size": _equals(False),
    "agent.adam_betas": _equals([0.9, 0.999]),
    "agent.weight_decay_parts": _equals(None),
    "agent.adam_eps": _equals(1.0e-8),
    "agent.fused_adam": _always,  # the same maths either way; fused Adam is always used now
    "agent.std_ceiling": _equals(None),
    "agent.std_ceiling_frames": _always,  # only agent.std_ceiling (above) switched it on
    "env.cpu_recipe": _always,  # the per-task part of +profile=cpu; its values are under agent.* and eval.*
    "eval.interval": _equals(None),
}
# retired keys that another key replaced: their one-line error names it instead of an ablation
REPLACED = {"eval.interval": "eval.every_frames (frames between evaluations, not iterations)"}


def drop_retired(cfg: DictConfig) -> DictConfig:
    """``cfg`` without its retired keys (``RETIRED``), where dropping them changes nothing, or a
    one-line ``ValueError`` naming the option the run used and the tag that still has it."""
    for key, harmless in RETIRED.items():
        parent, _, name = key.rpartition(".")
        node = OmegaConf.select(cfg, parent) if parent else cfg
        if not isinstance(node, DictConfig) or name not in node:
            continue
        value = OmegaConf.to_container(node, resolve=True)[name]
        if not harmless(value, cfg) and key in REPLACED:
            raise ValueError(f"{key} was replaced by {REPLACED[key]}; give that instead")
        if not harmless(value, cfg):
            raise ValueError(
                f"{key}={value!r}: this option was retired after its ablation (docs/ablations.md); "
                f"git checkout {RETIRED_TAG} to train, resume or evaluate with it"
            )
        with _unlocked(node):
            del node[name]
    return cfg


class _unlocked:
    """Struct mode off inside the block (a saved or composed config may be in struct mode)."""

    def __init__(self, node: DictConfig) -> None:
        self.node, self.before = node, OmegaConf.is_struct(node)

    def __enter__(self) -> DictConfig:
        OmegaConf.set_struct(self.node, False)
        return self.node

    def __exit__(self, *exc) -> None:
        OmegaConf.set_struct(self.node, self.before)


# -- type, choice and range errors as one line


def _known_keys(key: str) -> list[str]:
    parent = key.rpartition(".")[0]
    node = OmegaConf.select(schema(), parent) if parent else schema()
    return [f"{parent}.{k}" if parent else k for k in node] if isinstance(node, DictConfig) else []


# OmegaConf's type errors, said as the rest of the project says them
_TYPE_ERRORS = (
    (r"Value '(.*)' of type '\w+' could not be converted to Integer", "{key} must be an integer, got {0}"),
    (r"Value '(.*)' of type '\w+' could not be converted to Float", "{key} must be a number, got {0}"),
    (r"Value '(.*)' is not a valid bool \(type \w+\)", "{key} must be true or false, got {0}"),
    (r"Invalid value '(.*)', expected one of \[(.*)\]", "{key} must be one of {1}, got {0}"),
)


def _one_line(err: OmegaConfBaseException) -> str:
    key = str(err.full_key or "")
    if isinstance(err, ConfigKeyError):
        key = f"{key}.{err.key}" if err.key and not key.endswith(str(err.key)) else key
        close = difflib.get_close_matches(key, _known_keys(key), n=1)
        hint = f"; did you mean {close[0]}?" if close else ""
        return f"{key} is not a config key{hint} (the keys: docs/keys.md)"
    message = str(err).splitlines()[0]
    for pattern, template in _TYPE_ERRORS:
        found = re.fullmatch(pattern, message)
        if found and key:
            return template.format(*found.groups(), key=key)
    return f"{key}: {message}" if key else message


def check_ranges(cfg: DictConfig, node_type: type = TrainConfig, prefix: str = "") -> None:
    """Raise a one-line ``ValueError`` for the first value outside its field's bounds."""
    limits = {"gt": (lambda v, b: v > b, ">"), "ge": (lambda v, b: v >= b, ">=")}
    limits |= {"lt": (lambda v, b: v < b, "<"), "le": (lambda v, b: v <= b, "<=")}
    hints = get_type_hints(node_type)
    for f in fields(node_type):
        value = cfg[f.name]
        if is_dataclass(hints[f.name]):
            check_ranges(value, hints[f.name], f"{prefix}{f.name}.")
            continue
        if value is None or isinstance(value, bool) or not isinstance(value, int | float):
            continue
        for name, bound in f.metadata.items():
            ok, sign = limits[name]
            if not (math.isfinite(value) and ok(value, bound)):
                raise ValueError(f"{prefix}{f.name} must be {sign} {bound:g}, got {value!r}")


FRAME_KEYS = ("total_frames", "env.budget_frames", "eval.every_frames")  # counts of frames


def typed_config(cfg: DictConfig | Mapping) -> DictConfig:
    """``cfg`` (composed by Hydra, or saved) resolved, its retired keys dropped, merged over the
    schema's defaults and range-checked: a typed config in struct mode, or a one-line ``ValueError``."""
    plain = cfg if isinstance(cfg, DictConfig) else OmegaConf.create(dict(cfg))
    try:
        plain = OmegaConf.create(OmegaConf.to_container(plain, resolve=True))
    except OmegaConfBaseException as err:
        raise ValueError(_one_line(err)) from None
    plain = drop_retired(plain)
    for key in FRAME_KEYS:  # 2M, 2_000_000 and 2e6 alike
        value = OmegaConf.select(plain, key)
        if value is not None:
            OmegaConf.update(plain, key, frame_count(value, key))
    try:
        typed = OmegaConf.merge(schema(), plain)
    except (ValidationError, ConfigKeyError) as err:
        raise ValueError(_one_line(err)) from None
    check_ranges(typed)
    OmegaConf.set_struct(typed, True)
    return typed


def run_config(saved: DictConfig | Mapping | Path | str) -> DictConfig:
    """A saved run's config (its ``config.yaml``, or a checkpoint's ``config``) as today's typed
    config: keys added since it was saved take their defaults (:func:`typed_config`)."""
    if isinstance(saved, Path | str):
        path = Path(saved)
        try:
            saved = OmegaConf.load(path)
        except Exception as err:  # yaml's errors have several types
            first = str(err).splitlines()[0] if str(err) else type(err).__name__
            raise ValueError(f"{path} cannot be read as YAML ({first})") from None
    return typed_config(saved)


def plain(cfg: DictConfig) -> dict:
    """``cfg`` as plain Python values (choices as strings), as a checkpoint or a logger stores it."""
    return OmegaConf.to_container(cfg, resolve=True, enum_to_str=True)


# -- the two config groups whose order matters

ORDERED_GROUPS = ("exp", "profile")  # conf/train.yaml lists them in this order, after the rest


def hydra_overrides(args: Sequence[str]) -> list[str]:
    """Command-line ``args`` with ``+exp=X`` and ``+profile=Y`` written as ``exp=X`` and
    ``profile=Y``.

    ``conf/train.yaml`` lists ``exp`` and then ``profile`` in its defaults, so a profile always
    composes on top of the experiment whatever the order on the command line (Hydra would
    append ``+`` groups in command-line order instead); ``+exp=`` stays the way to name an
    experiment, as the paper's commands do.
    """
    out = []
    for arg in args:
        for group in ORDERED_GROUPS:
            if arg.startswith(f"+{group}="):
                arg = arg[1:]
        out.append(arg)
    return out


def device_error(device: str) -> str | None:
    """Why ``device`` cannot run a model here (one line), or None for ``cpu`` or an available
    ``cuda[:<index>]``."""
    try:
        kind = torch.device(str(device)).type
    except RuntimeError:
        kind = None
    if kind not in ("cpu", "cuda"):
        return f"device must be cpu or cuda[:<index>], got {device!r}"
    if kind == "cuda" and not torch.cuda.is_available():
        return f"device={device} but this machine has no CUDA device; use device=cpu"
    return None


# -- checks across keys, and what a run settles before it starts


def check_config(cfg: DictConfig) -> None:
    """One-line ``ValueError``s for what the schema cannot say of a typed config: keys that must
    agree with each other, the device, and the task's ``env.overrides``."""
    from roto_trl.envs.factory import task_config  # loads the simulator: only when checking a run

    a = cfg.agent
    if cfg.env.num_envs * a.rollout_len < a.minibatches:
        raise ValueError("agent.minibatches exceeds one rollout's frames (env.num_envs * agent.rollout_len)")
    if a.critic_encoder_sizes is not None:
        if a.shared_encoder:
            raise ValueError(
                "agent.critic_encoder_sizes sizes the critic's own encoder: give it with "
                "agent.shared_encoder=false, or leave it null"
            )
        if not a.critic_encoder_sizes or min(a.critic_encoder_sizes) < 1:
            raise ValueError(
                f"agent.critic_encoder_sizes must be a list of positive integers such as [256, 128], "
                f"got {list(a.critic_encoder_sizes)}"
            )
    weight = cfg.ssl.pos_weight
    if not (
        weight == "auto" or (isinstance(weight, int | float) and not isinstance(weight, bool) and weight > 0)
    ):
        raise ValueError(f"ssl.pos_weight must be a number > 0 or auto, got {weight!r}")
    unknown = sorted(set(cfg.env.obs_keys) - {"prop", "tactile"})
    if unknown or not cfg.env.obs_keys:
        raise ValueError(
            f"env.obs_keys must be a non-empty list of prop and tactile, got {list(cfg.env.obs_keys)}"
        )
    if a.precision == Precision.bfloat16 and not on_cpu(cfg.device):
        raise ValueError(
            "agent.precision=bfloat16 rounds oneDNN's CPU matrix products; "
            f"with device={cfg.device} use float32"
        )
    error = device_error(cfg.device)
    if error is not None:
        raise ValueError(error)
    task_config(str(cfg.env.task), **OmegaConf.to_container(cfg.env.overrides, resolve=True))


def checked_config(cfg: DictConfig | Mapping) -> DictConfig:
    """``cfg`` typed (:func:`typed_config`) and checked (:func:`check_config`)."""
    typed = typed_config(cfg)
    check_config(typed)
    return typed


def settle_for_machine(cfg: DictConfig) -> list[str]:
    """Settle what depends on the profile and this machine, in ``cfg``, so that the run's saved
    config holds it: ``agent.rollout_len`` raised to ``agent.min_rollout_len``, and
    ``agent.precision=auto`` resolved. Returns a line for each change, to print."""
    notes = []
    a = cfg.agent
    if a.min_rollout_len is not None and a.rollout_len < a.min_rollout_len:
        notes.append(
            f"agent.rollout_len: {a.rollout_len} -> {a.min_rollout_len} (agent.min_rollout_len; "
            f"agent.min_rollout_len=null keeps {a.rollout_len})"
        )
        a.rollout_len = a.min_rollout_len
    if a.precision == Precision.auto:
        a.precision = resolved_precision("auto", str(cfg.device))
        why = "bfloat16 products are a CPU path"
        if on_cpu(cfg.device):
            why = f"a CPU {'with' if cpu_has_bfloat16() else 'without'} bfloat16 products in hardware"
        notes.append(f"agent.precision: auto -> {a.precision} (device={cfg.device}: {why})")
    if a.precision == Precision.bfloat16 and not cpu_has_bfloat16():
        notes.append(
            "warning: agent.precision=bfloat16 on a CPU without AVX512-BF16 or AMX: torch emulates its "
            "matrix products, slower than float32; set agent.precision=float32"
        )
    return notes


def compose_train(overrides: Sequence[str] = ()) -> DictConfig:
    """The config ``roto_trl/train.py`` composes from ``conf/`` with command-line ``overrides``
    (``+exp=`` and ``+profile=`` in any order, :func:`hydra_overrides`), untyped as Hydra gives it:
    for tools and tests that build a run without the command line."""
    from hydra import compose, initialize_config_dir

    from roto_trl.utils.resources import resource_dir

    with initialize_config_dir(str(resource_dir("conf")), version_base="1.3"):
        return compose("train", overrides=hydra_overrides(overrides))


# overrides that change what an experiment trains: its task, observations or objective
IDENTITY_KEYS = ("env", "env.task", "env.obs_keys", "env.last_action", "ssl", "ssl.name")


def check_run_name(overrides: Sequence[str]) -> None:
    """A one-line ``ValueError`` when command-line ``overrides`` change what the run trains (its
    task, observation set or self-supervised objective, ``IDENTITY_KEYS``) but keep the
    experiment's name: runs are stored under, and the analysis tools group them by,
    ``exp_name``, so ``+exp=bounce_ppo ssl=fd`` must say ``exp_name=<its own name>``. Without
    ``+exp=`` the task alone may change: the default name follows it (``<task>_ppo``)."""
    keys = [arg.partition("=")[0].lstrip("+~") for arg in hydra_overrides(overrides)]
    changed = [k for k in keys if k in IDENTITY_KEYS]
    if not changed or "exp_name" in keys:
        return
    if "exp" not in keys and set(changed) <= {"env", "env.task"}:
        return
    raise ValueError(
        f"{', '.join(changed)} changes what the run trains; name it with exp_name=<name> "
        "(runs are stored and grouped by exp_name)"
    )
