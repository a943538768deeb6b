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
attribute ``run_dir`` points back. The study's storage and reports live in ``roto_trl/sweeps/``.
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
from pathlib import Path

import optuna

from roto_trl.sweeps.report import default_name, fmt, write_best, write_summary
from roto_trl.sweeps.storage import load_study
from roto_trl.utils.resources import TRAIN_SCRIPT, resource_dir


def parse_args(argv: list[str]) -> tuple[argparse.Namespace, list[str]]:
    """The command, its options and its trailing ``key=value`` overrides; argparse's one-line
    error (exit status 2) for anything else."""
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
    return args, overrides


def main(argv: list[str] | None = None) -> int:
    args, overrides = parse_args(sys.argv[1:] if argv is None else argv)
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
    print(f"best trial {study.best_trial.number} (objective {fmt(study.best_value)}): {study.best_params}")
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
