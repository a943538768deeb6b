"""The plugin class Hydra instantiates for ``hydra/sweeper=optuna``; the work is in ``_study``."""

from __future__ import annotations

import sys
from typing import Any

from hydra.plugins.sweeper import Sweeper
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig

from hydra_plugins.roto_optuna_sweeper.config import OptunaSweeperConf


class OptunaSweeper(Sweeper):
    """Runs trials of an Optuna study (TPE, maximising the task's return value), ``n_jobs`` at a
    time through the configured launcher.

    Args (``hydra.sweeper.<key>``, defaults in ``config.OptunaSweeperConf``):
        params: search space, ``key: sweep`` in Hydra's syntax: ``choice(a, b)``, ``a,b``,
            ``interval(lo, hi)``, ``range(start, stop[, step])``, each optionally inside
            ``tag(log, ...)``; ``tag(int, interval(...))`` samples integers. Sweeps given on the
            command line join the space; plain ``key=value`` arguments are passed to every trial.
        n_trials: the study ends when it holds this many COMPLETE trials, counted over every
            worker and earlier (resumed) sweeps; failed trials do not count.
        n_jobs: trials launched at once, as one batch of the configured launcher
            (``hydra/launcher=joblib hydra.launcher.n_jobs=<n>``: in parallel; Hydra's basic
            launcher runs a batch one trial after another).
        n_startup_trials, seed: TPE's random start-up trials and its seed (null: fresh entropy;
            a set seed is offset by the study's trial count, so a resumed sweep does not replay
            its first proposals).
        study_name, storage: the study (default: the sweep directory's name) and where it lives
            (default ``sqlite:///<sweep dir>/study.db``; any SQLAlchemy URL; ``journal://<file>``).
        max_failures: stop after this many failed trials in a row (a broken config never loops).
        heartbeat_interval, grace_period: liveness of running trials on RDB storages (seconds).
    """

    def __init__(self, **conf: Any) -> None:
        params = conf.pop("params", None) or {}
        self.conf = OptunaSweeperConf(params={str(k): str(v) for k, v in params.items()}, **conf)
        self.hydra_context: HydraContext | None = None
        self.config: DictConfig | None = None
        self.launcher = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        from hydra.core.plugins import Plugins

        self.hydra_context = hydra_context
        self.config = config
        self.launcher = Plugins.instance().instantiate_launcher(
            hydra_context=hydra_context, task_function=task_function, config=config
        )

    def sweep(self, arguments: list[str]) -> None:
        """Run the study; bad settings or a sweep directory it cannot write (exit status 2), a
        stop after ``max_failures`` (1) and Ctrl-C or SIGTERM (130) end the sweep with one line
        instead of a traceback."""
        import optuna

        from hydra_plugins.roto_optuna_sweeper._study import SweepStopped, run_sweep

        try:
            run_sweep(self, arguments)
        except ValueError as err:
            print(f"sweep: {err}", file=sys.stderr)
            sys.exit(2)
        except OSError as err:
            print(
                f"sweep: cannot write {err.filename or 'the sweep directory'}: {err.strerror}",
                file=sys.stderr,
            )
            sys.exit(2)
        except optuna.exceptions.StorageInternalError as err:
            cause = str(err.__cause__ or err).strip().splitlines()[0][:300]
            print(f"sweep: the study's storage failed: {cause}", file=sys.stderr)
            sys.exit(2)
        except SweepStopped as err:
            print(f"sweep: stopped: {err}", file=sys.stderr)
            sys.exit(1)
        except KeyboardInterrupt:
            print(
                "sweep: interrupted; the trials that were running are marked FAIL (interrupted). "
                "Run the same command again to go on",
                file=sys.stderr,
            )
            sys.exit(130)
