"""Training checkpoints: written atomically, read back with clear errors, loaded as a policy.

A checkpoint is one ``torch.save`` dict:
    agent, optimizer   state dicts (the agent's includes the value normaliser; the optimiser's
                       its learning rate, which ``agent.lr_schedule=kl_adaptive`` changes)
    aux                with an SSL objective: its loss (auxiliary networks, target encoder)
                       and its optimiser (``AuxiliaryUpdate.state_dict``)
    frames, iteration  progress counters; best_eval_metrics (the evaluation best.pt holds,
                       with its ``frames``; None before the first)
    policy_average     with agent.policy_ema_decay > 0: the moving average of the policy's weights,
                       by their names in the agent's state dict (``trainers.policy_average``)
    rng                torch, numpy and the training env's reset generator
    config             the run's resolved config (a plain dict)
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Any

import torch

from roto_trl.trainers.errors import WriteError
from roto_trl.trainers.policy_average import POLICY_AVERAGE_KEY, load_policy_weights

LATEST = "latest.pt"
BEST = "best.pt"
WEIGHTS = ("average", "trained")  # agent_from_checkpoint's choice of the policy's weights


def save_checkpoint(path: Path, state: dict[str, Any]) -> None:
    """Write ``state`` to ``path`` through a temporary file, so a kill never leaves half a file.

    Serialised in memory first, so that a failed write (a full disk) is a plain ``OSError``:
    the temporary file is removed and :class:`~roto_trl.trainers.errors.WriteError` names the
    path and the reason; ``path`` keeps its previous content.
    """
    buffer = io.BytesIO()
    torch.save(state, buffer)
    tmp = path.with_name(path.name + ".tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tmp.open("wb") as handle:
            handle.write(buffer.getbuffer())
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise WriteError(f"cannot write checkpoint {path}: {err.strerror.lower()}") from None


def load_checkpoint(path: Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Read a checkpoint, or raise ``FileNotFoundError`` / ``ValueError`` naming the problem."""
    path = Path(path)
    if path.is_dir():  # a run directory: its latest checkpoint
        path = path / "checkpoints" / LATEST
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path} (give a run directory or a .pt file it wrote)")
    try:
        state = torch.load(path, map_location=map_location, weights_only=False)
    except Exception as err:  # torch raises several types for a damaged file
        raise ValueError(f"checkpoint {path} cannot be read ({err}); use another one") from err
    missing = {"agent", "optimizer", "frames", "config"} - set(state)
    if missing:
        raise ValueError(f"{path} is not a RoTO-TRL training checkpoint (missing {sorted(missing)})")
    return state


def agent_from_checkpoint(state: dict[str, Any], env, weights: str = "average"):
    """The trained :class:`~roto_trl.modules.agent.Agent` of a loaded checkpoint, in eval mode.

    Build ``env`` from the checkpoint's own settings (``builders.make_task_env(state["config"],
    ...)``); a mismatch in observations or actions is reported, not silently accepted.
    ``weights`` (:data:`WEIGHTS`): ``average``, the policy's moving average when the run kept one
    (``agent.policy_ema_decay`` > 0; the controller its evaluations used), else its weights;
    ``trained``: the weights PPO trained, as a resumed run continues from them.
    """
    from roto_trl.trainers.builders import agent_for_env

    if weights not in WEIGHTS:
        raise ValueError(f"weights must be one of {list(WEIGHTS)}, got {weights!r}")
    agent = agent_for_env(state["config"], env)
    try:
        agent.load_state_dict(state["agent"])
        if weights == "average" and POLICY_AVERAGE_KEY in state:
            load_policy_weights(agent, state[POLICY_AVERAGE_KEY])
    except RuntimeError as err:
        raise ValueError(f"the checkpoint does not fit this env's observations/actions: {err}") from err
    return agent.eval()


def policy_from_checkpoint(state: dict[str, Any], env):
    """The deterministic policy of a loaded checkpoint (see :func:`agent_from_checkpoint`), as a
    function from the env's output to actions."""
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    agent = agent_from_checkpoint(state, env)

    def act(td):
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            return agent.policy(td.select(*agent.obs_keys).clone())["action"]

    return act
