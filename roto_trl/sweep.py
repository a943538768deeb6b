"""Sweeps: where a study lives, its summary, and its best trial as a new experiment.

    python -m roto_trl.sweep summary sweeps/bounce_fd-dynamics     # summary.md + PNG plots there
    python -m roto_trl.sweep best sweeps/bounce_fd-dynamics        # conf/exp/<name>.yaml, 5 seeds
    python -m roto_trl.sweep best sweeps/bounce_fd-dynamics --name bounce_fd_tuned --seeds 3 --run
    python -m roto_trl.sweep best sweeps/find_ppo-ppo --run +profile=quickstart  # at the sweep's budget
    python -m roto_trl.sweep summary DIR --storage postgresql://user:pw@host/db --study bounce_fd-dynamics

A sweep is ``python roto_trl/train.py -m +exp=<exp> hparams_search=<space>`` (the Optuna sweeper
of ``hydra_plugins/roto_optuna_sweeper``). Its directory holds ``study.json`` (study name and
storage, password hidden), ``study.db`` (the default SQLite storage) and ``trials/<number>/``: each
trial's run directory, with ``trial.json`` (study, storage, trial number); the trial's user
attribute ``run_dir`` points back. The storage helpers here are shared with the sweeper.
"""

from __future__ import annotations

import argparse
import json
import math
import random
import re
import shlex
import subprocess
import sys
import time
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
import optuna
import sqlalchemy.exc
from omegaconf import OmegaConf
from optuna.distributions import CategoricalDistribution
from optuna.trial import FrozenTrial, TrialState

from roto_trl.resources import resource_dir

STUDY_FILE = "study.json"  # in the sweep directory: which study (name, storage) it belongs to
TRIAL_FILE = "trial.json"  # in a trial's run directory: which study and trial it is
DEFAULT_DB = "study.db"  # the default storage: SQLite in the sweep directory
JOURNAL = "journal://"  # storage prefix of an Optuna journal file: journal://<path>
RDB_SCHEMES = ("sqlite", "postgresql", "mysql")
TABLE_RACE_ATTEMPTS = 5  # tries to open a fresh database that other workers are creating tables in
TRAIN_SCRIPT = Path(__file__).resolve().parent / "train.py"


# ---------------------------------------------------------------------------- storage


def storage_url(storage: str | None, sweep_dir: Path) -> str:
    """The study's storage: ``storage`` as given, or SQLite in the sweep directory."""
    return storage or f"sqlite:///{(Path(sweep_dir) / DEFAULT_DB).resolve()}"


def redact(url: str) -> str:
    """``url`` with its password (``scheme://user:password@host``) replaced by ``***``."""
    return re.sub(r"(://[^:/@]*:)[^@/]*@", r"\1***@", url)


def open_storage(
    url: str, *, heartbeat_interval: int | None = None, grace_period: int | None = None
) -> optuna.storages.BaseStorage:
    """The Optuna storage at ``url``.

    ``journal://<path>`` is a ``JournalStorage`` on a file (``journal:///abs/path.log``; on a
    shared file system for many machines); ``sqlite://``, ``postgresql[+driver]://`` and
    ``mysql[+driver]://`` are SQLAlchemy URLs for ``RDBStorage``, which records heartbeats of
    running trials every ``heartbeat_interval`` seconds when one is given. Workers starting at
    once on a fresh database race to create Optuna's tables (PostgreSQL's ``CREATE ... IF NOT
    EXISTS`` is not atomic): the loser gets a duplicate-key error, waits and opens it again.
    """
    if url.startswith(JOURNAL):
        path = Path(url.removeprefix(JOURNAL))
        path.parent.mkdir(parents=True, exist_ok=True)
        return optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(str(path)))
    scheme = url.split("://", 1)[0].split("+", 1)[0] if "://" in url else ""
    if scheme not in RDB_SCHEMES:
        raise ValueError(
            f"storage {redact(url)!r}: unknown kind; use sqlite:///<file>, postgresql://<user>@<host>/<db>, "
            f"mysql://..., or {JOURNAL}<file>"
        )
    for attempt in range(1, TABLE_RACE_ATTEMPTS + 1):
        try:
            return _rdb_storage(url, heartbeat_interval, grace_period)
        except (sqlalchemy.exc.IntegrityError, sqlalchemy.exc.ProgrammingError):
            if attempt == TABLE_RACE_ATTEMPTS:
                raise
            time.sleep(0.5 + random.random())  # let the winner finish creating the tables


def _rdb_storage(
    url: str, heartbeat_interval: int | None, grace_period: int | None
) -> optuna.storages.RDBStorage:
    with warnings.catch_warnings():  # heartbeats are "experimental" in Optuna since 2.9
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        try:
            return optuna.storages.RDBStorage(
                url,
                engine_kwargs={"pool_pre_ping": True},  # survive connections dropped during long trials
                heartbeat_interval=heartbeat_interval,
                grace_period=grace_period,
            )
        except ImportError as err:
            raise ValueError(f"storage {redact(url)!r} needs a database driver: {err}") from None


def record_study(sweep_dir: Path, study_name: str, storage: str | None) -> None:
    """Write ``<sweep_dir>/study.json``: the study this directory belongs to (no password;
    storage null: ``study.db`` in this directory, wherever it is moved)."""
    info = {"study_name": study_name, "storage": redact(storage) if storage else None}
    (Path(sweep_dir) / STUDY_FILE).write_text(json.dumps(info, indent=2) + "\n")


def load_study(sweep_dir: Path, storage: str | None = None, study_name: str | None = None) -> optuna.Study:
    """The study of a sweep directory (``study.json``), or of ``storage`` and ``study_name``."""
    sweep_dir = Path(sweep_dir)
    if not sweep_dir.is_dir():
        raise FileNotFoundError(f"no sweep directory {sweep_dir}")
    info_path = sweep_dir / STUDY_FILE
    info = json.loads(info_path.read_text()) if info_path.is_file() else {}
    if not info and (storage is None or study_name is None):
        raise FileNotFoundError(f"{sweep_dir} holds no {STUDY_FILE}; give --storage and --study")
    url = storage_url(storage or info.get("storage"), sweep_dir)
    if "***@" in url:
        raise ValueError(f"the storage in {info_path} hides its password; give it with --storage URL")
    name = study_name or info["study_name"]
    try:
        return optuna.load_study(study_name=name, storage=open_storage(url))
    except KeyError:
        raise ValueError(f"no study {name!r} in {redact(url)}") from None


# ---------------------------------------------------------------------------- summary


def _fmt(value) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def _param_names(trials: list[FrozenTrial]) -> list[str]:
    names: list[str] = []
    for trial in trials:
        names += [name for name in trial.params if name not in names]
    return names


def importances(study: optuna.Study) -> tuple[dict[str, float], str]:
    """Each parameter's importance over the complete trials (Optuna's default evaluator,
    PED-ANOVA), or ``{}`` and why not."""
    complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if len(complete) < 2:
        return {}, "needs at least 2 complete trials"
    try:
        return optuna.importance.get_param_importances(study), ""
    except (ValueError, RuntimeError) as err:  # e.g. all objectives equal
        return {}, str(err)


def trial_rows(study: optuna.Study) -> list[str]:
    """The trials as a Markdown table: number, state, objective, parameters, duration, where."""
    trials = study.get_trials(deepcopy=False)
    names = _param_names(trials)
    lines = [
        "| # | state | objective | " + " | ".join(names) + " | minutes | run dir or fail reason |",
        "|---" * (len(names) + 5) + "|",
    ]
    for trial in trials:
        value = _fmt(trial.value) if trial.value is not None else ""
        params = [_fmt(trial.params[n]) if n in trial.params else "" for n in names]
        minutes = f"{trial.duration.total_seconds() / 60:.1f}" if trial.duration else ""
        where = trial.user_attrs.get("run_dir", "")
        if trial.state == TrialState.FAIL:
            where = trial.user_attrs.get("fail_reason", "no report: its worker stopped (heartbeat lost)")
        lines.append(
            f"| {trial.number} | {trial.state.name} | {value} | {' | '.join(params)} | {minutes} | {where} |"
        )
    return lines


def plot_study(study: optuna.Study, out_dir: Path, importance: dict[str, float]) -> list[Path]:
    """``history.png`` (objective per trial, best so far), ``params.png`` (objective against each
    parameter) and, when known, ``importance.png``; returns the paths written."""
    import matplotlib.pyplot as plt  # here: the sweeper plugin imports this module at Hydra's start
    from matplotlib.ticker import MaxNLocator, NullFormatter

    from roto_trl.plots import save_figure  # selects the Agg backend

    trials = study.get_trials(deepcopy=False)
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    failed = [t.number for t in trials if t.state == TrialState.FAIL]
    paths = []

    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot([t.number for t in complete], [t.value for t in complete], "o", label="complete")
    if complete:
        best_so_far = np.maximum.accumulate([t.value for t in complete])
        ax.step([t.number for t in complete], best_so_far, where="post", color="C1", label="best so far")
    for i, number in enumerate(failed):
        ax.axvline(number, color="C3", alpha=0.3, label="failed" if i == 0 else None)
    ax.set(xlabel="trial", ylabel="objective", title=study.study_name)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.legend()
    paths.append(save_figure(fig, out_dir / "history.png"))

    names = _param_names(complete)
    if names:
        cols = min(3, len(names))
        rows = math.ceil(len(names) / cols)
        fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 3 * rows), squeeze=False)
        for ax, name in zip(axes.flat, names, strict=False):
            shown = [t for t in complete if name in t.params]
            dist = shown[0].distributions[name]
            if isinstance(dist, CategoricalDistribution):
                x = [dist.to_internal_repr(t.params[name]) for t in shown]
                ax.set_xticks(range(len(dist.choices)), [_fmt(c) for c in dist.choices])
                ax.set_xlim(-0.5, len(dist.choices) - 0.5)
            else:
                x = [t.params[name] for t in shown]
                if dist.log:
                    ax.set_xscale("log")
                    ax.xaxis.set_minor_formatter(NullFormatter())
            ax.plot(x, [t.value for t in shown], "o", alpha=0.7)
            ax.set(xlabel=name, ylabel="objective")
        for ax in list(axes.flat)[len(names) :]:
            ax.axis("off")
        paths.append(save_figure(fig, out_dir / "params.png"))

    if importance:
        fig, ax = plt.subplots(figsize=(6, 1.5 + 0.4 * len(importance)))
        ax.barh(list(importance)[::-1], list(importance.values())[::-1])
        ax.set(xlabel="importance (PED-ANOVA)", title=study.study_name)
        paths.append(save_figure(fig, out_dir / "importance.png"))
    return paths


def write_summary(study: optuna.Study, out_dir: Path) -> Path:
    """Write ``summary.md`` and the plots of ``plot_study`` into ``out_dir``; returns the Markdown."""
    out_dir = Path(out_dir)
    trials = study.get_trials(deepcopy=False)
    counts = Counter(t.state.name for t in trials)
    lines = [
        f"# Sweep {study.study_name}",
        "",
        f"{len(trials)} trials ({', '.join(f'{n} {s.lower()}' for s, n in counts.items()) or 'none yet'}). "
        "Objective (maximised): each run's mean evaluation return over its last evaluations "
        "(`roto_trl.train.run_objective`).",
        "",
    ]
    importance, why_not = importances(study)
    if counts.get("COMPLETE"):
        best = study.best_trial
        lines += [f"## Best trial: {best.number}, objective {_fmt(best.value)}", ""]
        lines += ["| parameter | value |", "|---|---|"]
        lines += [f"| {k} | {_fmt(v)} |" for k, v in best.params.items()]
        lines += ["", f"Run directory: `{best.user_attrs.get('run_dir', '?')}`", ""]
    lines += ["## Parameter importance (PED-ANOVA over the complete trials)", ""]
    if importance:
        lines += ["| parameter | importance |", "|---|---|"]
        lines += [f"| {k} | {v:.3f} |" for k, v in importance.items()] + [""]
    else:
        lines += [f"Not available: {why_not}.", ""]
    lines += ["## Trials", "", *trial_rows(study), ""]
    for path in plot_study(study, out_dir, importance):
        lines += [f"![{path.stem}]({path.name})", ""]
    out = out_dir / "summary.md"
    out.write_text("\n".join(lines))
    return out


# ---------------------------------------------------------------------------- best trial


def _base_exp(arguments: list[str]) -> str | None:
    """The experiment (``+exp=<name>``) among a sweep's command-line arguments."""
    for arg in arguments:
        key, _, value = arg.lstrip("+").partition("=")
        if key == "exp":
            return value
    return None


def best_config(study: optuna.Study, name: str) -> str:
    """An ``exp/`` config: the sweep's experiment with the best trial's values, as YAML text."""
    complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if not complete:
        raise ValueError(f"study {study.study_name!r} has no complete trial yet")
    best = study.best_trial
    arguments = list(study.user_attrs.get("arguments", []))
    base = _base_exp(arguments)
    shown = ("exp", "hparams_search", *best.params)  # in the config, or not a setting
    others = [a for a in arguments if a.lstrip("+").partition("=")[0] not in shown]
    body = OmegaConf.create({"defaults": [base, "_self_"] if base else ["_self_"], "exp_name": name})
    for key, value in best.params.items():
        OmegaConf.update(body, key, value, force_add=True)
    header = [
        "# @package _global_",
        f"# Study {study.study_name}, best of {len(complete)} complete trials: trial {best.number}, "
        f"objective {_fmt(best.value)} ({best.user_attrs.get('run_dir', '?')}).",
        f"# The experiment {base} with the tuned values; written by python -m roto_trl.sweep best."
        if base
        else "# The tuned values on train.yaml's defaults; written by python -m roto_trl.sweep best.",
    ]
    if others:
        header.append(f"# The sweep also ran with (not applied here): {' '.join(others)}")
    return "\n".join(header) + "\n" + OmegaConf.to_yaml(body)


def write_best(study: optuna.Study, name: str, conf_dir: Path, *, force: bool = False) -> Path:
    """Write ``best_config`` as ``<conf_dir>/exp/<name>.yaml``; returns its path."""
    if not re.fullmatch(r"[A-Za-z0-9_][\w-]*", name):
        raise ValueError(f"--name {name!r}: use letters, digits, '_' and '-'")
    path = Path(conf_dir) / "exp" / f"{name}.yaml"
    if path.exists() and not force:
        raise FileExistsError(f"{path} exists; pick another --name or pass --force")
    text = best_config(study, name)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def default_name(study_name: str) -> str:
    """``<study name>_best`` with '-' as '_': ``bounce_fd-dynamics`` -> ``bounce_fd_dynamics_best``."""
    return re.sub(r"\W", "_", study_name) + "_best"


# ---------------------------------------------------------------------------- command line


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m roto_trl.sweep", description=__doc__.split("\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    for command, text in (
        ("summary", "write summary.md and PNG plots of the study into the sweep directory"),
        (
            "best",
            "write the best trial as conf/exp/<name>.yaml and print (or --run) its seeds; trailing "
            "key=value arguments join that command (e.g. the sweep's budget: +profile=quickstart)",
        ),
    ):
        sub = commands.add_parser(command, help=text, description=text)
        sub.add_argument("sweep_dir", type=Path, help="the sweep directory (sweeps/<exp_name>-<space>)")
        sub.add_argument("--storage", help="storage URL (default: the one in <sweep_dir>/study.json)")
        sub.add_argument("--study", help="study name (default: the one in <sweep_dir>/study.json)")
        if command == "best":
            sub.add_argument("--name", help="the new experiment (default: <study name>_best)")
            sub.add_argument("--seeds", type=int, default=5, help="seeds 0..N-1 to run it over (default 5)")
            sub.add_argument("--run", action="store_true", help="run those seeds now (Hydra multirun)")
            sub.add_argument("--force", action="store_true", help="overwrite conf/exp/<name>.yaml")
            sub.add_argument(
                "--conf-dir",
                type=Path,
                default=resource_dir("conf"),
                help="write <conf-dir>/exp/<name>.yaml (default: the conf/ train.py reads; another one "
                "joins the command through hydra.searchpath)",
            )
    args, overrides = parser.parse_known_args(argv)
    unknown = [a for a in overrides if args.command != "best" or "=" not in a or a.startswith("-")]
    if unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        study = load_study(args.sweep_dir, args.storage, args.study)
        if args.command == "summary":
            print(f"summary: {write_summary(study, args.sweep_dir).resolve()}")
            return 0
        if args.seeds < 1:
            raise ValueError(f"--seeds must be >= 1, got {args.seeds}")
        name = args.name or default_name(study.study_name)
        path = write_best(study, name, args.conf_dir, force=args.force)
    except (ValueError, FileNotFoundError, FileExistsError) as err:
        raise SystemExit(f"sweep: {err}") from None
    print(f"best trial {study.best_trial.number} (objective {_fmt(study.best_value)}): {study.best_params}")
    print(f"experiment: {path}")
    command = [
        sys.executable,
        str(TRAIN_SCRIPT),
        "-m",
        f"+exp={name}",
        f"seed={','.join(map(str, range(args.seeds)))}",
    ]
    if Path(args.conf_dir).resolve() != resource_dir("conf").resolve():
        command.append(f"hydra.searchpath=[file://{Path(args.conf_dir).resolve()}]")
    command += overrides
    print("run it:", shlex.join(command))
    return subprocess.run(command, check=False).returncode if args.run else 0


if __name__ == "__main__":
    sys.exit(main())
