"""What resuming a run may change, and how its directory is brought back to its checkpoint.

* :func:`resume_config`: a resumed run keeps its saved config; only ``RESUMABLE`` keys may be
  given with ``resume=`` (to extend the budget), any other override is a one-line error.
* :func:`finished_reason`: a run that reached its budget is left as it is.
* :func:`rewind`: the logs are cut back to the checkpoint's frame count and ``best.pt`` is made
  to agree with the checkpoint's ``best_eval_metrics``, so a resumed run reads as one
  uninterrupted run.
"""

from __future__ import annotations

import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from roto_trl.trainers.checkpoint import BEST, LATEST, load_checkpoint
from roto_trl.trainers.loggers import truncate_csv_logs

RESUMABLE = ("total_frames", "time_limit_minutes", "progress")  # what may change on resume


def override_keys(overrides: Sequence[str]) -> list[str]:
    """The config keys of Hydra command-line overrides (``+a.b=1`` -> ``a.b``), Hydra's own left out."""
    keys = [o.split("=", 1)[0].lstrip("+~") for o in overrides]
    return [k for k in keys if not k.startswith("hydra.") and k != "resume"]


def resume_config(saved: DictConfig, given: DictConfig, overrides: Sequence[str]) -> DictConfig:
    """The saved config of a resumed run with the ``RESUMABLE`` values of ``given`` that the
    command line ``overrides``; any other override raises a one-line ``ValueError``."""
    keys = override_keys(overrides)
    other = [k for k in keys if k not in RESUMABLE]
    if other:
        raise ValueError(
            f"resume= continues a run with its saved config; only {', '.join(RESUMABLE)} may change "
            f"on resume, not {', '.join(other)} (start a new run for other values)"
        )
    cfg = saved.copy()
    for key in keys:
        OmegaConf.update(cfg, key, OmegaConf.select(given, key))
    return cfg


def finished_reason(cfg: DictConfig, state: dict[str, Any]) -> str | None:
    """Why a run with checkpoint ``state`` has nothing left to do under ``cfg``, or None."""
    frames = int(state["frames"])
    if frames >= cfg.total_frames:
        return f"it is finished at {frames:,} frames (total_frames={cfg.total_frames})"
    limit, wall = cfg.time_limit_minutes, float(state.get("wall_time", 0.0))
    if limit is not None and wall >= 60 * float(limit):
        return f"it used its time limit (time_limit_minutes={limit}, {wall / 60:.1f} min trained)"
    return None


def rewind(run_dir: Path, state: dict[str, Any]) -> dict[str, int]:
    """Bring ``run_dir`` back to its latest checkpoint ``state``: cut ``train.csv``, ``eval.csv``
    and ``aux.csv`` to its frame count and reconcile ``best.pt`` (:func:`reconcile_best`).

    Returns the rows dropped per file.
    """
    dropped = truncate_csv_logs(run_dir, int(state["frames"]))
    reconcile_best(Path(run_dir) / "checkpoints", state)
    return dropped


def reconcile_best(ckpt_dir: Path, latest: dict[str, Any]) -> None:
    """Make ``best.pt`` the checkpoint that ``latest``'s ``best_eval_metrics`` describes.

    Training writes ``latest.pt`` before ``best.pt`` at a new best, so the two can disagree only
    when a kill fell between the two writes (``best.pt`` then is older and the best policy is
    ``latest.pt`` itself: it is copied) or ``best.pt`` comes from iterations after the checkpoint
    that the resume discards (it is removed and ``latest``'s best is forgotten, in place: the
    next evaluation writes a new one).
    """
    path = ckpt_dir / BEST
    best_at = (latest.get("best_eval_metrics") or {}).get("frames")
    best_frames = int(load_checkpoint(path)["frames"]) if path.is_file() else None
    if best_frames == best_at:
        return
    if best_at == int(latest["frames"]):
        shutil.copyfile(ckpt_dir / LATEST, path)
    else:
        path.unlink(missing_ok=True)
        latest["best_eval_metrics"] = None
