"""A finished (or running) sweep as a report: its trials, parameter importances and plots
(``summary.md``), and its best trial written as a new ``exp/`` config."""

from __future__ import annotations

import math
import re
from collections import Counter
from pathlib import Path

import numpy as np
import optuna
from omegaconf import DictConfig, OmegaConf
from optuna.distributions import CategoricalDistribution
from optuna.trial import FrozenTrial, TrialState

from roto_trl.utils.resources import resource_dir


def fmt(value) -> str:
    """A parameter or objective value for tables: floats to 4 significant digits."""
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def _param_names(trials: list[FrozenTrial]) -> list[str]:
    names: list[str] = []
    for trial in trials:
        names += [name for name in trial.params if name not in names]
    return names


MIN_TRIALS_FOR_IMPORTANCE = 10  # fewer trials give importances that are mostly noise


def importances(study: optuna.Study) -> tuple[dict[str, float], str]:
    """Each parameter's importance over the complete trials (Optuna's default evaluator,
    PED-ANOVA), or ``{}`` and why not."""
    complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if len(complete) < MIN_TRIALS_FOR_IMPORTANCE:
        return {}, f"needs at least {MIN_TRIALS_FOR_IMPORTANCE} complete trials, has {len(complete)}"
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
        value = fmt(trial.value) if trial.value is not None else ""
        params = [fmt(trial.params[n]) if n in trial.params else "" for n in names]
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

    from roto_trl.analysis.plots import save_figure  # selects the Agg backend

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
                ax.set_xticks(range(len(dist.choices)), [fmt(c) for c in dist.choices])
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


def objective_name(study: optuna.Study) -> str:
    """What the study's trial values are: the sweeper's ``objective`` (studies from before it was
    configurable maximised the evaluation return)."""
    objective = study.user_attrs.get("objective", "return_mean")
    return "headline metric of the task" if objective == "headline" else f"`{objective}`"


def write_summary(study: optuna.Study, out_dir: Path) -> Path:
    """Write ``summary.md`` and the plots of ``plot_study`` into ``out_dir``; returns the Markdown."""
    out_dir = Path(out_dir)
    trials = study.get_trials(deepcopy=False)
    counts = Counter(t.state.name for t in trials)
    lines = [
        f"# Sweep {study.study_name}",
        "",
        f"{len(trials)} trials ({', '.join(f'{n} {s.lower()}' for s, n in counts.items()) or 'none yet'}). "
        f"Objective (maximised): each run's mean {objective_name(study)} over its last evaluations "
        "(`roto_trl.analysis.runs.run_objective`).",
        "",
    ]
    importance, why_not = importances(study)
    if counts.get("COMPLETE"):
        best = study.best_trial
        lines += [f"## Best trial: {best.number}, objective {fmt(best.value)}", ""]
        lines += ["| parameter | value |", "|---|---|"]
        lines += [f"| {k} | {fmt(v)} |" for k, v in best.params.items()]
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


def base_exp_config(base: str, conf_dir: Path) -> DictConfig:
    """The experiment ``base`` as its file in ``<conf_dir>/exp/`` or the package's ``conf/exp/``
    has it, or a ``ValueError`` naming where it was looked for."""
    for root in (Path(conf_dir), resource_dir("conf")):
        path = root / "exp" / f"{base}.yaml"
        if path.is_file():
            return OmegaConf.load(path)
    raise ValueError(
        f"the sweep's experiment {base!r} is in neither {conf_dir}/exp/ nor the package's conf/exp/"
    )


def best_config(study: optuna.Study, name: str, conf_dir: Path) -> str:
    """An ``exp/`` config: the sweep's experiment (its file's contents, so that the new one stands
    alone in the ``exp`` group) with the best trial's values, as YAML text."""
    complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if not complete:
        raise ValueError(f"study {study.study_name!r} has no complete trial yet")
    best = study.best_trial
    arguments = list(study.user_attrs.get("arguments", []))
    base = _base_exp(arguments)
    shown = ("exp", "hparams_search", *best.params)  # in the config, or not a setting
    others = [a for a in arguments if a.lstrip("+").partition("=")[0] not in shown]
    body = base_exp_config(base, conf_dir) if base else OmegaConf.create()
    body.exp_name = name
    for key, value in best.params.items():
        OmegaConf.update(body, key, value, force_add=True)
    header = [
        "# @package _global_",
        f"# Study {study.study_name}, best of {len(complete)} complete trials: trial {best.number}, "
        f"objective {fmt(best.value)} ({best.user_attrs.get('run_dir', '?')}).",
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
    text = best_config(study, name, conf_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def default_name(study_name: str) -> str:
    """``<study name>_best`` with '-' as '_': ``bounce_fd-dynamics`` -> ``bounce_fd_dynamics_best``."""
    return re.sub(r"\W", "_", study_name) + "_best"
