"""The study loop behind ``OptunaSweeper``: search space, trials, failures, resumption.

* **Trials.** ``n_jobs`` at a time per worker: Optuna's TPE proposes values (with its constant
  liar when ``n_jobs > 1``, so that trials running at once are not proposed alike), each trial
  runs as one Hydra job with ``run_dir=<sweep dir>/trials/<number>`` (that directory also gets
  ``trial.json``: study, storage without password, trial number; the trial gets user attributes
  ``run_dir`` and ``worker`` = ``host:pid``), the batch goes to the configured launcher in one
  ``launch`` (``hydra/launcher=joblib`` runs it in parallel processes, ``submitit_slurm`` as SLURM
  jobs; Hydra's basic launcher one after another), and each job's return value is its trial's
  objective (maximised).
* **The target.** The sweep ends once the study holds ``n_trials`` COMPLETE trials, counted over
  every worker and every earlier run of the same command. Each worker checks before it launches a
  batch and launches no more than the target lacks, so k workers running at once may end with up
  to (k - 1) x ``n_jobs`` more.
* **Failures.** A trial whose run raises (a NaN/inf stop, a crash, an impossible combination of
  values) or returns no finite number is FAIL with user attribute ``fail_reason`` (the run's
  traceback in ``<run dir>/error.txt``) and does not count; the sweep goes on. ``max_failures``
  failures in a row stop the worker with an error, so a broken setup never loops.
* **Resumption.** Run the same command again: it finds the same study (``load_if_exists``),
  keeps the completed trials and marks FAIL, never reruns, each RUNNING trial whose worker is dead:

  - started on this host by a process that no longer exists (user attribute ``worker``): marked at
    once, which is what resuming a killed single-machine sweep needs;
  - no heartbeat for ``grace_period`` seconds (RDB storages record one every
    ``heartbeat_interval`` seconds; Optuna's ``fail_stale_trials``): a worker lost on another
    machine. A live worker elsewhere keeps beating, so its RUNNING trial is left alone.

  JournalStorage keeps no heartbeats: there a dead worker's trial on another machine stays
  RUNNING (it never counts and never runs again). Hosts are told apart by name: containers that
  share one study need distinct host names (Docker and Kubernetes give each its own).
"""

from __future__ import annotations

import json
import math
import os
import re
import socket
import threading
import traceback
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import optuna
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import ChoiceSweep, IntervalSweep, Override, RangeSweep
from hydra.core.utils import JobReturn
from hydra.plugins.sweeper import Sweeper
from optuna.distributions import BaseDistribution, CategoricalDistribution, FloatDistribution, IntDistribution
from optuna.trial import Trial, TrialState

from roto_trl.analysis.runs import run_objective
from roto_trl.sweeps.report import write_summary
from roto_trl.sweeps.storage import TRIAL_FILE, open_storage, record_study, redact, storage_url
from roto_trl.utils.paths import writable_dir

TAGS = {"log", "int"}  # tag(log, ...): log scale; tag(int, interval(...)): integers
RESERVED = ("run_dir", "resume")  # set by the sweeper for each trial
_PLAIN = re.compile(r"[A-Za-z_/][\w/.-]*")  # strings Hydra reads back unquoted as themselves


class SweepStopped(RuntimeError):
    """The sweep cannot go on (``max_failures`` failed trials in a row); reported in one line."""


def distribution(override: Override) -> BaseDistribution:
    """The Optuna distribution of one Hydra sweep: ``choice``/``a,b`` -> categorical,
    ``range`` -> int (or float) with its step, ``interval`` -> float (int with the ``int`` tag);
    the ``log`` tag samples on a log scale."""
    sweep, key = override.value(), override.get_key_element()
    if not isinstance(sweep, ChoiceSweep | RangeSweep | IntervalSweep):
        raise ValueError(f"{override.input_line}: use choice(), range() or interval() in a sweep")
    unknown = sweep.tags - TAGS
    if unknown:
        raise ValueError(f"{key}: unknown tag {sorted(unknown)}; known: {sorted(TAGS)}")
    log_scale = "log" in sweep.tags
    if isinstance(sweep, ChoiceSweep):
        if sweep.tags:
            raise ValueError(f"{key}: choice() takes no tags")
        if any(isinstance(value, dict | list) for value in sweep.list):
            raise ValueError(f"{key}: choices must be numbers, strings, booleans or null")
        return CategoricalDistribution(sweep.list)
    if isinstance(sweep, RangeSweep):
        values = list(sweep.range())
        if not values:
            raise ValueError(f"{override.input_line}: the range is empty")
        kind = IntDistribution if all(isinstance(v, int) for v in values) else FloatDistribution
        return kind(min(values), max(values), step=abs(sweep.step), log=log_scale)
    if "int" in sweep.tags:
        return IntDistribution(int(sweep.start), int(sweep.end), log=log_scale)
    return FloatDistribution(sweep.start, sweep.end, log=log_scale)


def search_space(overrides: list[Override]) -> tuple[dict[str, tuple[str, BaseDistribution]], list[str]]:
    """Split ``overrides`` into the search space (``name -> (override key, distribution)``, the
    name without ``+``) and fixed overrides for every trial; a later override of a key wins."""
    last: dict[str, Override] = {}
    for override in overrides:
        last.pop(override.key_or_group, None)
        last[override.key_or_group] = override
    reserved = [key for key in RESERVED if key in last]
    if reserved:
        raise ValueError(f"a sweep sets {reserved[0]} for each trial (<sweep dir>/trials/<number>); drop it")
    space, fixed = {}, []
    for name, override in last.items():
        if override.is_sweep_override():
            space[name] = (override.get_key_element(), distribution(override))
        else:
            fixed.append(override.input_line)
    return space, fixed


def render(value: Any) -> str:
    """``value`` as Hydra override text that reads back as the same value."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, int | float):
        return repr(value)
    text = str(value)
    if _PLAIN.fullmatch(text) and text.lower() not in ("true", "false", "null", "inf", "nan"):
        return text
    return "'" + text.replace("'", "\\'") + "'"


def suggest(trial: Trial, name: str, dist: BaseDistribution) -> Any:
    if isinstance(dist, CategoricalDistribution):
        return trial.suggest_categorical(name, dist.choices)
    if isinstance(dist, IntDistribution):
        return trial.suggest_int(name, dist.low, dist.high, step=dist.step, log=dist.log)
    return trial.suggest_float(name, dist.low, dist.high, step=dist.step, log=dist.log)


def _first_value(dist: BaseDistribution) -> Any:
    return dist.choices[0] if isinstance(dist, CategoricalDistribution) else dist.low


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


@contextmanager
def heartbeats(storage: optuna.storages.BaseStorage, trial_ids: list[int]) -> Iterator[None]:
    """Record a heartbeat of each of ``trial_ids`` every heartbeat interval while the block runs
    (RDB storages with one; what ``Study.optimize`` does for its single trial)."""
    interval = storage.get_heartbeat_interval() if isinstance(storage, optuna.storages.RDBStorage) else None
    if not interval:
        yield
        return
    stop = threading.Event()

    def beat() -> None:
        while True:
            for trial_id in trial_ids:
                storage.record_heartbeat(trial_id)
            if stop.wait(interval):
                return

    thread = threading.Thread(target=beat, name="trial-heartbeats", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


def _failure(job: JobReturn, run_dir: Path) -> str | None:
    """Why ``job`` gives no objective (its traceback to ``run_dir/error.txt``), or None."""
    try:
        value = job.return_value
    except Exception as err:
        (run_dir / "error.txt").write_text("".join(traceback.format_exception(err)))
        first_line = (str(err).strip().splitlines() or [""])[0]
        return f"{type(err).__name__}: {first_line}"[:500]
    if isinstance(value, bool) or not isinstance(value, int | float):
        return f"the run returned {value!r}, not a number"
    if not math.isfinite(value):
        return f"the objective is {value}, not finite"
    return None


class StudyLoop:
    """One worker of a sweep: the study, its search space, and this worker's run of failures.

    ``sweeper`` is the plugin (``sweeper.OptunaSweeper``, set up by Hydra): its ``conf``,
    ``config``, ``hydra_context`` and ``launcher`` are read here. Typed as Hydra's ``Sweeper`` so
    that this module never imports ``sweeper.py``, which imports this one when a sweep starts.
    """

    def __init__(self, sweeper: Sweeper, arguments: list[str]) -> None:
        conf, config = sweeper.conf, sweeper.config
        for key in ("n_trials", "n_jobs", "max_failures", "heartbeat_interval", "grace_period"):
            if getattr(conf, key) < 1:
                raise ValueError(f"hydra.sweeper.{key} must be >= 1, got {getattr(conf, key)}")
        parser = OverridesParser.create(config_loader=sweeper.hydra_context.config_loader)
        params = [f"{key}={value}" for key, value in conf.params.items()]
        self.space, self.fixed = search_space(parser.parse_overrides([*params, *arguments]))
        if not self.space and params:
            fixed = sorted(conf.params)
            raise ValueError(
                "nothing to search: the command line fixes every key of the search space "
                f"({', '.join(fixed)}); leave at least one of them out, or give it as a sweep such as "
                "'agent.lr=interval(1e-5, 1e-3)'"
            )
        if not self.space:
            raise ValueError(
                "nothing to search: pick a space with hparams_search=<name> (conf/hparams_search/) "
                "or give sweeps such as 'agent.lr=tag(log, interval(1e-5, 1e-3))'"
            )
        self.sweeper, self.conf = sweeper, conf
        self.sweep_dir = Path(str(config.hydra.sweep.dir)).resolve()
        # compose one trial's config now: a bad key fails here, before any trial exists
        probe = [f"{key}={render(_first_value(dist))}" for key, dist in self.space.values()]
        sweeper.validate_batch_is_legal([[*self.fixed, *probe, f"run_dir={render(str(self.sweep_dir))}"]])

        writable_dir(self.sweep_dir, "hydra.sweep.dir")  # a one-line error before the study opens
        self.url = storage_url(conf.storage, self.sweep_dir)
        self.storage = open_storage(
            self.url, heartbeat_interval=conf.heartbeat_interval, grace_period=conf.grace_period
        )
        study_name = conf.study_name or self.sweep_dir.name
        self.study = optuna.create_study(
            storage=self.storage,
            study_name=study_name,
            direction="maximize",
            load_if_exists=True,  # resume, or join the other workers
            pruner=optuna.pruners.NopPruner(),
        )
        self.study_id = self.storage.get_study_id_from_name(study_name)
        self.study.set_user_attr("arguments", list(arguments))  # for `python -m roto_trl.sweep best`
        self.study.set_user_attr("objective", str(conf.objective))  # what the trials' values are
        record_study(self.sweep_dir, study_name, conf.storage)
        self.failures, self.last_failure = 0, ""

    def count(self, *states: TrialState) -> int:
        return len(self.study.get_trials(deepcopy=False, states=states or None))

    def run(self) -> None:
        """Run trials until the study holds ``n_trials`` complete ones; then write its summary."""
        conf, name = self.conf, self.study.study_name
        print(
            f"sweep: study {name} in {redact(self.url)}: {self.count(TrialState.COMPLETE)} of "
            f"{conf.n_trials} trials complete; sweep directory {self.sweep_dir}",
            flush=True,
        )
        while True:
            self.fail_dead_trials()
            if self.count(TrialState.COMPLETE) >= conf.n_trials:
                break
            if self.failures >= conf.max_failures:
                raise SweepStopped(
                    f"{self.failures} trials in a row failed (the last: {self.last_failure}); "
                    "fix that and run the same command again to go on"
                )
            # a set seed moves with the study's size: a resumed sweep does not replay its proposals
            seed = None if conf.seed is None else conf.seed + self.count()
            self.study.sampler = optuna.samplers.TPESampler(
                n_startup_trials=conf.n_startup_trials, seed=seed, constant_liar=conf.n_jobs > 1
            )
            self.run_batch(min(conf.n_jobs, conf.n_trials - self.count(TrialState.COMPLETE)))
        summary = write_summary(self.study, self.sweep_dir)
        best = self.study.best_trial
        print(
            f"sweep: {self.count(TrialState.COMPLETE)} trials complete; best: trial {best.number}, objective "
            f"{best.value:.4g}, {best.params}\nsweep: summary {summary}; make it an experiment: "
            f"python -m roto_trl.sweep best {self.sweep_dir}",
            flush=True,
        )

    def run_batch(self, size: int) -> None:
        """Ask for ``size`` trials, run them as one launch of the configured launcher, tell results."""
        with warnings.catch_warnings():  # heartbeats are recorded by heartbeats(), not optimize()
            warnings.filterwarnings("ignore", "Heartbeat of storage is supposed to be used with")
            trials = [self.study.ask() for _ in range(size)]
        overrides = [self.trial_overrides(trial) for trial in trials]
        ids = [self.storage.get_trial_id_from_study_id_trial_number(self.study_id, t.number) for t in trials]
        try:
            with heartbeats(self.storage, ids):
                jobs = self.sweeper.launcher.launch(overrides, initial_job_idx=trials[0].number)
        except BaseException as err:  # interrupted, or the launcher itself broke: no trial ran to its end
            reason = "interrupted" if isinstance(err, KeyboardInterrupt) else f"{type(err).__name__}: {err}"
            for trial in trials:
                trial.set_user_attr("fail_reason", reason[:500])
                self.study.tell(trial, state=TrialState.FAIL)
            raise
        for trial, job in zip(trials, jobs, strict=True):
            self.tell(trial, job)

    def trial_overrides(self, trial: Trial) -> list[str]:
        """Propose one trial's values; its run directory (with ``trial.json``) and Hydra overrides."""
        values = {name: suggest(trial, name, dist) for name, (_, dist) in self.space.items()}
        run_dir = self.sweep_dir / "trials" / str(trial.number)
        trial.set_user_attr("run_dir", str(run_dir))
        trial.set_user_attr("worker", f"{socket.gethostname()}:{os.getpid()}")
        run_dir.mkdir(parents=True, exist_ok=True)
        link = {
            "study_name": self.study.study_name,
            "storage": redact(self.url),
            "trial_number": trial.number,
        }
        (run_dir / TRIAL_FILE).write_text(json.dumps({**link, "params": values}, indent=2) + "\n")
        return [
            *self.fixed,
            *(f"{self.space[name][0]}={render(value)}" for name, value in values.items()),
            f"run_dir={render(str(run_dir))}",
        ]

    def tell(self, trial: Trial, job: JobReturn) -> None:
        """The trial is COMPLETE with its job's objective, or FAIL with the reason."""
        reason = _failure(job, Path(trial.user_attrs["run_dir"]))
        if reason is None:
            self.failures = 0
            self.study.tell(trial, float(job.return_value))
            return
        trial.set_user_attr("fail_reason", reason)
        self.failures, self.last_failure = self.failures + 1, reason
        print(f"sweep: trial {trial.number} failed: {reason}", flush=True)
        self.study.tell(trial, state=TrialState.FAIL)

    def fail_dead_trials(self) -> None:
        """Mark FAIL the RUNNING trials of dead workers (the module's docstring says which)."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            optuna.storages.fail_stale_trials(self.study)
        host = socket.gethostname()
        for trial in self.study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
            worker = trial.user_attrs.get("worker", "")
            worker_host, _, pid = worker.rpartition(":")
            if worker_host != host or not pid.isdigit() or _alive(int(pid)):
                continue
            trial_id = self.storage.get_trial_id_from_study_id_trial_number(self.study_id, trial.number)
            value = finished_value(Path(trial.user_attrs.get("run_dir", "")), self.conf.objective)
            try:
                if value is not None:  # its run finished before the worker died: keep its result
                    self.storage.set_trial_state_values(trial_id, TrialState.COMPLETE, [value])
                else:
                    self.storage.set_trial_user_attr(trial_id, "fail_reason", f"its worker {worker} died")
                    self.storage.set_trial_state_values(trial_id, TrialState.FAIL)
            except optuna.exceptions.UpdateFinishedTrialError:
                continue  # another worker marked it first
            what = f"COMPLETE (its run had finished: {value:.4g})" if value is not None else "FAIL"
            print(
                f"sweep: trial {trial.number} was left RUNNING by dead worker {worker}: marked {what}",
                flush=True,
            )


def finished_value(run_dir: Path, objective: str) -> float | None:
    """The objective of a trial whose run finished (``summary.json`` written), or None."""
    if not (run_dir / "summary.json").is_file():
        return None
    try:
        value = run_objective(run_dir, objective)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def run_sweep(sweeper: Sweeper, arguments: list[str]) -> None:
    StudyLoop(sweeper, arguments).run()
