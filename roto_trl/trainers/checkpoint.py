"""Training checkpoints: written atomically, read back with clear errors, loaded as a policy.

A checkpoint is one ``torch.save`` dict:
    agent, optimizer   state dicts (the agent's includes the value normaliser; the optimiser's
                       its learning rate, which ``agent.lr_schedule=kl_adaptive`` changes)
    aux                with an SSL objective: its loss (auxiliary networks, target encoder)
                       and its optimiser (``AuxiliaryUpdate.state_dict``)
    frames, iteration, best_eval_metrics, wall_time, eval_time
                       the run's progress (``TrainState.state_dict``)
    rng                torch, numpy, Python and the training env's reset generator
    config             the run's resolved config (a plain dict)
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Any

import torch

from roto_trl.config import run_config
from roto_trl.trainers.errors import WriteError

LATEST = "latest.pt"
BEST = "best.pt"
REQUIRED = (
    "agent",
    "optimizer",
    "frames",
    "iteration",
    "best_eval_metrics",
    "wall_time",
    "eval_time",
    "config",
)


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
    """Read a checkpoint, its ``config`` as today's typed config (``roto_trl.config.run_config``),
    or raise ``FileNotFoundError`` / ``ValueError`` naming the problem."""
    path = Path(path)
    if path.is_dir():  # a run directory: its latest checkpoint
        path = path / "checkpoints" / LATEST
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path} (give a run directory or a .pt file it wrote)")
    try:
        state = torch.load(path, map_location=map_location, weights_only=False)
    except Exception as err:  # torch raises several types for a damaged file
        raise ValueError(f"checkpoint {path} cannot be read ({err}); use another one") from err
    missing = sorted(set(REQUIRED) - set(state)) if isinstance(state, dict) else list(REQUIRED)
    if missing:
        raise ValueError(f"{path} is not a RoTO-TRL training checkpoint (missing {missing})")
    try:
        state["config"] = run_config(state["config"])
    except ValueError as err:
        raise ValueError(f"checkpoint {path}: {err}") from None
    return state


def agent_from_checkpoint(state: dict[str, Any], env):
    """The trained :class:`~roto_trl.modules.agent.Agent` of a loaded checkpoint, in eval mode.

    Build ``env`` from the checkpoint's own settings (``builders.make_task_env(state["config"],
    ...)``); a mismatch in observations or actions is reported, not silently accepted.
    """
    from roto_trl.trainers.builders import agent_for_env

    agent = agent_for_env(state["config"], env)
    try:
        agent.load_state_dict(state["agent"])
    except RuntimeError as err:
        first = str(err).splitlines()[1].strip() if len(str(err).splitlines()) > 1 else str(err)
        raise ValueError(f"the checkpoint does not fit this env's observations/actions ({first})") from None
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


class RunCheckpoints:
    """A run's ``checkpoints/latest.pt`` and ``best.pt``, kept so that its logs never run ahead of
    ``latest.pt``: a failed write cuts ``logger``'s files back to the last good checkpoint.

    Args:
        run_dir: the run's directory.
        logger: the run's ``MetricLogger``.
        saved_frames: the frames ``latest.pt`` already holds (a resumed run's), or None.
    """

    def __init__(self, run_dir: Path, logger, saved_frames: int | None = None) -> None:
        self.dir = Path(run_dir) / "checkpoints"
        self.logger = logger
        self.saved_frames = saved_frames

    def save(self, name: str, state: dict[str, Any]) -> None:
        """Write ``state`` (a checkpoint dict with its ``frames``) as ``name``."""
        try:
            save_checkpoint(self.dir / name, state)
        except WriteError as err:
            self.logger.truncate(self.saved_frames or 0)
            raise WriteError(f"{err}; the logs are cut back to the last checkpoint") from None
        if name == LATEST:
            self.saved_frames = int(state["frames"])
