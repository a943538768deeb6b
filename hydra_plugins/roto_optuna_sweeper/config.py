"""The sweeper's config, ``hydra/sweeper=optuna`` (see ``sweeper.OptunaSweeper`` for its keys).

No ``from __future__ import annotations`` here: Hydra's plugin scanner runs this module before it
is in ``sys.modules``, where ``dataclass`` cannot resolve string annotations.
"""

from dataclasses import dataclass, field

from hydra.core.config_store import ConfigStore


@dataclass
class OptunaSweeperConf:
    """Keys of ``hydra.sweeper`` when ``hydra/sweeper=optuna``."""

    _target_: str = "hydra_plugins.roto_optuna_sweeper.sweeper.OptunaSweeper"
    params: dict[str, str] = field(default_factory=dict)  # key -> Hydra sweep (choice, interval, range)
    objective: str = "headline"  # maximised: the task's headline metric, or an eval.csv column (return_mean)
    n_trials: int = 20  # stop once the study holds this many COMPLETE trials (all workers together)
    n_jobs: int = 1  # trials launched at once, through hydra/launcher (joblib: in parallel processes)
    n_startup_trials: int = 5  # TPE's random trials before it models the results
    seed: int | None = None  # sampler seed; null: fresh entropy (what workers sharing a study need)
    study_name: str | None = None  # null: the sweep directory's name
    storage: str | None = None  # null: sqlite:///<sweep dir>/study.db; or an SQLAlchemy URL, journal://<file>
    max_failures: int = 10  # stop the sweep after this many failed trials in a row (of this worker)
    heartbeat_interval: int = 60  # seconds between a running trial's heartbeats (RDB storages)
    grace_period: int = 180  # a RUNNING trial without a heartbeat for this long belongs to a dead worker


ConfigStore.instance().store(
    group="hydra/sweeper", name="optuna", node=OptunaSweeperConf, provider="roto_trl"
)
