"""A multirun job's share of the machine's cores, from the Hydra launcher that runs it.

Jobs that run side by side on one machine must split its cores, or ``n_jobs x threads`` threads
fight over them. A job's share sets both its torch threads and its physics threads
(``torch_threads`` and ``env.overrides.num_threads``; either, when given, wins).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


def job_threads(launcher: Mapping[str, Any], cores: int) -> int | None:
    """Threads for one job of a multirun on ``cores`` cores, or None to keep the defaults.

    * joblib (``hydra/launcher=joblib``): ``cores // n_jobs`` (at least 1); ``n_jobs=-1`` means
      one job per core, ``-2`` one fewer, as in joblib.
    * submitit (``submitit_local``, ``submitit_slurm``, ``slurm``): ``cpus_per_task`` (at most
      ``cores``); unset: the defaults, which on SLURM are the cores the job was given.
    * any other launcher (Hydra's basic one runs jobs one after another): the defaults.
    """
    settings = {"_target_": "", "n_jobs": None, "cpus_per_task": None, **launcher}  # each launcher has some
    target = str(settings["_target_"]).lower()
    if "joblib" in target:
        n_jobs = int(settings["n_jobs"] or 1)
        concurrent = n_jobs if n_jobs > 0 else max(1, cores + 1 + n_jobs)
        return max(1, cores // concurrent)
    if "submitit" in target and settings["cpus_per_task"]:
        return max(1, min(int(settings["cpus_per_task"]), cores))
    return None
