"""A run's directory: where a new run, a resumed one or a multirun job trains, what resuming may
change, and how the directory is brought back to its checkpoint.

* :func:`prepare_run`: the run's config, directory and (resuming) checkpoint, with the lock held.
* :func:`place_multirun_job`: a multirun job's directory and share of the cores.
* :func:`resume_config`: a resumed run keeps its saved config; only ``RESUMABLE`` keys may be
  given with ``resume=`` (to extend the budget), any other override is a one-line error.
* :func:`finished_reason`: a run that reached its budget is left as it is.
* :func:`rewind`: the logs are cut back to the checkpoint's frame count and ``best.pt`` is made
  to agree with the checkpoint's ``best_eval_metrics``, so a resumed run reads as one
  uninterrupted run.
"""

from __future__ import annotations

import os
import shlex
import shutil
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf, open_dict

from roto_trl.config import check_config, plain, run_config
from roto_trl.trainers.checkpoint import BEST, LATEST, load_checkpoint
from roto_trl.trainers.interrupts import stop_with_parent
from roto_trl.trainers.loggers import truncate_csv_logs
from roto_trl.trainers.provenance import read_provenance
from roto_trl.trainers.run_lock import RunLock
from roto_trl.trainers.threads import job_threads
from roto_trl.utils.paths import writable_dir

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
    limit, wall = cfg.time_limit_minutes, float(state["wall_time"])
    if limit is not None and wall >= 60 * float(limit):
        return f"it used its time limit (time_limit_minutes={limit}, {wall / 60:.1f} min trained)"
    return None


def rewind(run_dir: Path, state: dict[str, Any]) -> None:
    """Bring ``run_dir`` back to its latest checkpoint ``state``: cut ``train.csv``, ``eval.csv``
    and ``aux.csv`` to its frame count (saying in one line what was dropped) and reconcile
    ``best.pt`` (:func:`reconcile_best`)."""
    dropped = truncate_csv_logs(run_dir, int(state["frames"]))
    if any(dropped.values()):
        rows = ", ".join(f"{n} of {kind}.csv" for kind, n in dropped.items() if n)
        print(f"resume: dropped the rows logged after the checkpoint ({rows})")
    loaded = Path(state["loaded_from"]) if "loaded_from" in state else Path(run_dir) / "checkpoints" / LATEST
    if loaded.name == LATEST:  # resumed from best.pt: best.pt is that checkpoint already
        reconcile_best(Path(run_dir) / "checkpoints", state)


def reconcile_best(ckpt_dir: Path, latest: dict[str, Any]) -> None:
    """Make ``best.pt`` the checkpoint that ``latest``'s ``best_eval_metrics`` describes.

    Training writes ``latest.pt`` before ``best.pt`` at a new best, so the two can disagree only
    when a kill fell between the two writes (``best.pt`` then is older and the best policy is
    ``latest.pt`` itself: it is copied) or ``best.pt`` comes from iterations after the checkpoint
    that the resume discards (it is removed and ``latest``'s best is forgotten, in place: the
    next evaluation writes a new one).
    """
    path = ckpt_dir / BEST
    best_at = (latest["best_eval_metrics"] or {"frames": None})["frames"]
    try:
        best_frames = int(load_checkpoint(path)["frames"]) if path.is_file() else None
    except ValueError as err:  # a damaged best.pt: the resume needs only latest.pt
        print(f"resume: {err.args[0].split(' (')[0]}; it is replaced by the next best evaluation")
        best_frames = None
    if best_frames == best_at:
        return
    if best_at == int(latest["frames"]):
        shutil.copyfile(ckpt_dir / LATEST, path)
    else:
        path.unlink(missing_ok=True)
        latest["best_eval_metrics"] = None


def resume_target(resume: str) -> tuple[Path, Path]:
    """``(run directory, checkpoint)`` of ``resume=``: a run directory (its ``latest.pt``), or one
    of its checkpoints (``<run>/checkpoints/best.pt``, to go on from it when ``latest.pt`` is
    damaged); a ``FileNotFoundError`` for a path that is neither."""
    path = Path(resume)
    if path.suffix == ".pt":
        if path.parent.name != "checkpoints":
            raise FileNotFoundError(
                f"resume={path}: give a run directory or a checkpoint in its checkpoints/"
            )
        return path.parent.parent, path
    if not path.is_dir():
        raise FileNotFoundError(f"resume={path}: no such run directory")
    return path, path / "checkpoints" / LATEST


def no_checkpoint(run_dir: Path, checkpoint: Path) -> str:
    """Why ``resume=`` finds no checkpoint, and what to do instead."""
    if checkpoint.name != LATEST:
        return f"resume: no checkpoint at {checkpoint}"
    sittings = read_provenance(run_dir)
    if not sittings:
        command = f"python roto_trl/train.py ... run_dir={run_dir}"
    elif "overrides" in sittings[0]:  # a multirun job's command line is its launcher worker's
        command = shlex.join(["python", "roto_trl/train.py", *sittings[0]["overrides"]])
    else:  # a run recorded before the overrides were
        command = shlex.join(sittings[0]["command"])
    return (
        f"resume={run_dir}: the run stopped before its first checkpoint, so there is nothing to continue; "
        f"start it again with its command: {command}"
    )


# the keys that make a checkpoint's networks: config.yaml must agree with the checkpoint on them
SHAPE_KEYS = (
    "env.task",
    "env.obs_keys",
    "env.last_action",
    "env.overrides.history",
    "agent.shared_encoder",
    "agent.critic_encoder_sizes",
    "ssl.name",
)


def saved_config(run_dir: Path, state: dict[str, Any], checkpoint: Path) -> DictConfig:
    """The config a resumed run continues with: its ``config.yaml``, or the checkpoint's own copy
    where ``config.yaml`` is missing or cannot be read (said in one line; the resume writes it
    back). A ``config.yaml`` that disagrees with the checkpoint on what its networks are
    (``SHAPE_KEYS``) is a one-line ``ValueError``."""
    path = Path(run_dir) / "config.yaml"
    try:
        cfg = run_config(path) if path.is_file() else None
    except ValueError as err:
        print(f"resume: {err}; continuing with the config {checkpoint.name} holds")
        cfg = None
    if cfg is None:
        return state["config"].copy()
    for key in SHAPE_KEYS:
        ours, theirs = OmegaConf.select(cfg, key), OmegaConf.select(state["config"], key)
        if ours != theirs:
            raise ValueError(
                f"{path} has {key}={ours} but {checkpoint} was trained with {key}={theirs}: restore the "
                "run's own config.yaml (or resume the run that checkpoint belongs to)"
            )
    return cfg


def save_config(cfg: DictConfig, run_dir: Path) -> None:
    """Write the run's resolved config as ``<run_dir>/config.yaml``."""
    OmegaConf.save(OmegaConf.create(plain(cfg)), Path(run_dir) / "config.yaml")


def prepare_run(
    cfg: DictConfig, overrides: Sequence[str] = ()
) -> tuple[DictConfig, Path, dict | None, RunLock]:
    """The run's config, directory, (when resuming) checkpoint, and the directory's lock, held.

    A resumed run takes its own saved config (``<run dir>/config.yaml``) with the ``RESUMABLE``
    keys that the command line ``overrides`` change (:func:`resume_config`). Another process
    holding the directory is an error before anything in it is touched.
    """
    if cfg.resume:
        run_dir, checkpoint = resume_target(str(cfg.resume))
        lock = RunLock(writable_dir(run_dir, "resume")).acquire()
        try:
            if not checkpoint.is_file():
                raise FileNotFoundError(no_checkpoint(run_dir, checkpoint))
            state = load_checkpoint(checkpoint)
            state["loaded_from"] = str(checkpoint)  # what rewind() reconciles best.pt with
            new_cfg = resume_config(saved_config(run_dir, state, checkpoint), cfg, overrides)
            check_config(new_cfg)
        except BaseException:
            lock.release()
            raise
        return new_cfg, run_dir, state, lock
    if cfg.run_dir:
        run_dir = Path(str(cfg.run_dir))
    else:
        run_dir = Path("runs") / cfg.exp_name / f"{datetime.now():%Y%m%d-%H%M%S}-s{cfg.seed}"
    lock = RunLock(writable_dir(run_dir, "run_dir")).acquire()
    if (run_dir / "checkpoints" / LATEST).exists():
        lock.release()
        raise FileExistsError(f"{run_dir} already holds a run; continue it with resume={run_dir}")
    with open_dict(cfg):
        cfg.run_dir, cfg.resume = str(run_dir), None
    save_config(cfg, run_dir)
    return cfg, run_dir, None, lock


def place_multirun_job(cfg: DictConfig, hydra_cfg: DictConfig) -> bool:
    """Give a multirun job its run directory and its share of the cores (edits ``cfg``).

    The job's directory: its Hydra job directory (``hydra.sweep.dir`` / ``hydra.sweep.subdir``)
    without ``run_dir``; with one ``run_dir=X`` for several jobs, ``X/<job number>`` (our Optuna
    sweeper gives each trial its own ``run_dir``, kept as it is). The same on every start of the
    job: if it already holds a checkpoint, the job continues it, which is how a job requeued after
    the scheduler's time limit (submitit's requeue) resumes. Thread shares:
    ``roto_trl.trainers.threads.job_threads``.

    Returns:
        True when the job continues its directory's checkpoint (``cfg.resume`` set).
    """
    share = job_threads(hydra_cfg.launcher, len(os.sched_getaffinity(0)))
    if "joblib" in str(OmegaConf.select(hydra_cfg, "launcher._target_", default="")):
        stop_with_parent()  # a worker of a killed sweep stops instead of training on alone
    with open_dict(cfg):
        if share is not None:
            cfg.torch_threads = cfg.torch_threads or share
            if "num_threads" not in cfg.env.overrides:
                cfg.env.overrides.num_threads = share
        if cfg.resume:
            return False
        optuna = str(OmegaConf.select(hydra_cfg, "sweeper._target_", default="")).endswith("OptunaSweeper")
        if not cfg.run_dir:
            job_dir = Path(str(hydra_cfg.runtime.output_dir))
        elif optuna:
            job_dir = Path(str(cfg.run_dir))
        else:
            job_dir = Path(str(cfg.run_dir)) / str(hydra_cfg.job.num)
        if (job_dir / "checkpoints" / LATEST).exists():
            cfg.resume = str(job_dir)
            return True
        cfg.run_dir = str(job_dir)
        return False
