"""How a run was made: ``<run dir>/provenance.json``, one record per sitting (the first start and
each resume), so that a results table can tell runs of different code, packages or machines apart.

A record holds the git commit of the code and whether its tree had uncommitted changes, the
versions of Python, torch, torchrl, tensordict, MuJoCo and numpy, the CPU model and whether it
multiplies bfloat16 in hardware, the resolved matrix-product precision, the torch and physics
thread counts, the host, the start time, the command line as typed and the run's own Hydra
overrides (in a multirun the command line is the launcher's worker, so only the overrides say what
the job was given).
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from collections.abc import Sequence
from datetime import datetime
from importlib import metadata
from pathlib import Path
from typing import Any

import torch
from omegaconf import DictConfig

from roto_trl.modules.networks import cpu_has_bfloat16

FILE = "provenance.json"
PACKAGES = ("torch", "torchrl", "tensordict", "mujoco", "numpy", "hydra-core", "roto-trl")
SOURCE_DIR = Path(__file__).resolve().parents[2]  # the checkout's root, when the code is one
# where an untracked file can change what a run does; a log beside the checkout cannot
SOURCE_PATHS = ("roto_trl/", "conf/", "assets/", "hydra_plugins/")


def _git(root: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=10)


def git_state(root: Path = SOURCE_DIR) -> dict[str, Any]:
    """``commit`` (or None outside a git checkout) and ``dirty``: uncommitted changes to tracked
    files, or untracked files among the code, config and models (``SOURCE_PATHS``); an untracked
    log or output elsewhere in the checkout does not count."""
    try:
        commit, status = _git(root, "rev-parse", "HEAD"), _git(root, "status", "--porcelain", "-z")
    except (OSError, subprocess.TimeoutExpired):
        return {"commit": None, "dirty": None}
    if commit.returncode != 0:
        return {"commit": None, "dirty": None}
    changed = [entry for entry in status.stdout.split("\0") if entry]  # "XY path", paths unquoted
    dirty = any(not entry.startswith("??") or entry[3:].startswith(SOURCE_PATHS) for entry in changed)
    return {"commit": commit.stdout.strip(), "dirty": dirty}


def cpu_model() -> str:
    """The CPU's model name (Linux ``/proc/cpuinfo``), else what ``platform`` says."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def versions() -> dict[str, str | None]:
    def version(name: str) -> str | None:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return None

    return {"python": platform.python_version(), **{name: version(name) for name in PACKAGES}}


def physics_threads(cfg: DictConfig) -> int:
    """The physics worker threads: ``env.overrides.num_threads``, by default every usable core."""
    overrides = cfg.env.overrides
    return int(overrides["num_threads"]) if "num_threads" in overrides else len(os.sched_getaffinity(0))


def sitting_record(cfg: DictConfig, frames: int, overrides: Sequence[str]) -> dict[str, Any]:
    """What this sitting of the run is made of, starting at ``frames``; ``overrides`` are the run's
    own ``key=value`` arguments (Hydra's task overrides: a multirun job's include its sweep values)."""
    return {
        "started": datetime.now().astimezone().isoformat(timespec="seconds"),
        "at_frames": int(frames),
        **git_state(),
        "versions": versions(),
        "cpu": cpu_model(),
        "cpu_bfloat16": cpu_has_bfloat16(),
        "precision": str(cfg.agent.precision),
        "torch_threads": torch.get_num_threads(),
        "physics_threads": physics_threads(cfg),
        "device": str(cfg.device),
        "host": platform.node(),
        "command": [Path(sys.orig_argv[0]).name, *sys.orig_argv[1:]],  # as typed, before Hydra
        "overrides": list(overrides),
    }


def record_sitting(run_dir: Path, cfg: DictConfig, frames: int, overrides: Sequence[str]) -> dict[str, Any]:
    """Append this sitting's record to ``<run_dir>/provenance.json``; returns the record."""
    path = Path(run_dir) / FILE
    sittings = read_provenance(run_dir)
    record = sitting_record(cfg, frames, overrides)
    path.write_text(json.dumps([*sittings, record], indent=2))
    return record


def read_provenance(run_dir: Path) -> list[dict[str, Any]]:
    """The run's sitting records (none for a run made before provenance was kept)."""
    path = Path(run_dir) / FILE
    if not path.is_file():
        return []
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError:
        return []
    return data if isinstance(data, list) else []
