"""Figures and numbers from trained runs (the paper's Section 6 and Appendices A, B, E, H).

    python roto_trl/analyse.py curves 'runs/compare/bounce_*'          # return vs frames, physical metrics
    python roto_trl/analyse.py mi runs/compare/bounce_ppo-s0 runs/compare/bounce_fd-s0
    python roto_trl/analyse.py latent runs/compare/bounce_fd-s0       # 2-D PCA of z over one episode
    python roto_trl/analyse.py tactile runs/bounce_tfd/<run>          # predicted vs actual contacts
    python roto_trl/analyse.py aux-memory 'runs/baoding_fd*/*'        # auxiliary loss per minibatch
    python roto_trl/analyse.py table 'runs/multirun/*/*' --at 2.5M,5M --reference   # the results table
    python roto_trl/analyse.py compare 'runs/find_fd_bf16/*' --against 'runs/find_fd/*'  # paired by seed
    python roto_trl/analyse.py episodes runs/baoding_ppo/<run> --every 1M   # sampled policy vs controller

Runs are run directories of ``train.py`` or quoted globs of them. Each command writes PNGs and a
CSV of the numbers behind them to ``--out`` (default ``runs/analysis/<command>``) and prints
their paths. Commands that run an agent (mi, latent, tactile) use its ``--checkpoint``
(``best`` or ``latest``) on fresh evaluation worlds with the run's evaluation seed.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import roto_trl  # noqa: F401  first, before torch loads: sets how its OpenMP threads wait (roto_trl/__init__.py)

# isort: split
import matplotlib.pyplot as plt
import numpy as np
import torch

from roto_trl.analysis.checkpoint_eval import load_run
from roto_trl.analysis.compare import compare_runs, comparison_csv_rows, comparison_markdown
from roto_trl.analysis.episodes import run_windows, windows_csv_rows, windows_markdown
from roto_trl.analysis.metrics import describe
from roto_trl.analysis.mutual_information import latent_state_information, pca
from roto_trl.analysis.plots import save_figure
from roto_trl.analysis.rollouts import collect
from roto_trl.analysis.runs import (
    Run,
    by_experiment,
    countable,
    find_runs,
    headline_of,
    learning_curve,
    one_task,
    physical_metrics,
    run_csv,
)
from roto_trl.analysis.stability import default_marks, run_stability, stability_csv_rows, stability_markdown
from roto_trl.analysis.table import (
    load_reference,
    parse_frames,
    results_table,
    table_markdown,
    write_table_csv,
)
from roto_trl.trainers.builders import eval_seed, make_aux_update, make_eval_env
from roto_trl.trainers.loggers import read_csv

CONFUSION = ("tpr", "fpr", "fnr", "tnr", "accuracy", "precision")


def write_csv(path: Path, header: list[str], rows: list[list]) -> Path:
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        writer.writerows(rows)
    return path


# ---------------------------------------------------------------------------- curves


def cmd_curves(runs: list[Run], out: Path, args) -> list[Path]:
    """An evaluation metric vs frames (mean ± 1 std across seeds; ``--metric``, by default the
    task's headline metric) and the physical-metric bars."""
    one_task(runs, "curves")
    groups = by_experiment(runs)
    metric = args.metric or headline_of(runs[0].path) or "return_mean"
    fig, ax = plt.subplots(figsize=(6.5, 4))
    rows = []
    for exp, members in groups.items():
        curve = learning_curve(members, args.x, metric)
        ax.plot(curve.x, curve.mean, label=f"{exp} ({curve.seeds} seed{'' if curve.seeds == 1 else 's'})")
        ax.fill_between(curve.x, curve.mean - curve.std, curve.mean + curve.std, alpha=0.25)
        xs = curve.x.astype(int) if args.x == "frames" else curve.x
        rows += [[exp, x, m, s, curve.seeds] for x, m, s in zip(xs, curve.mean, curve.std, strict=True)]
    xlabel = "env steps (frames)" if args.x == "frames" else "training wall time (minutes)"
    what, unit = describe(metric)
    ax.set(xlabel=xlabel, ylabel=unit or what, title=f"{what} (mean ± 1 std over seeds)")
    ax.legend()
    name = "curves" if args.x == "frames" else "curves-minutes"
    written = [save_figure(fig, out / f"{name}.png")]
    header = ["exp_name", args.x, f"{metric}_mean", f"{metric}_std", "seeds"]
    written.append(write_csv(out / f"{name}.csv", header, rows))

    if args.no_physical:
        return written
    metrics = {exp: physical_metrics(members) for exp, members in groups.items()}
    names = list(next(iter(metrics.values())))
    fig, axes = plt.subplots(1, len(names), figsize=(3.2 * len(names), 3.6), squeeze=False)
    rows = []
    for ax, name in zip(axes[0], names, strict=True):
        x = np.arange(len(groups))
        means = [metrics[exp][name].mean() for exp in groups]
        maxes = [metrics[exp][name].max() for exp in groups]
        ax.bar(x, maxes, color="C0", alpha=0.3, label="max")
        ax.bar(x, means, color="C0", edgecolor="black", linewidth=1.5, label="mean")
        ax.set_xticks(x, list(groups), rotation=30, ha="right")
        ax.set_title(name)
        rows += [
            [exp, name, m, mx, len(metrics[exp][name])]
            for exp, m, mx in zip(groups, means, maxes, strict=True)
        ]
    axes[0, 0].legend()
    written.append(save_figure(fig, out / "physical.png"))
    written.append(write_csv(out / "physical.csv", ["exp_name", "metric", "mean", "max", "seeds"], rows))
    return written


# ---------------------------------------------------------------------------- agents on fresh worlds


def agent_runs(runs: list[Run], args):
    """Each run's agent and its deterministic trajectories (``args.worlds`` episodes)."""
    for run in runs:
        cfg, state, _ = load_run(run.path, args.checkpoint)
        agent, traj = collect(state, args.worlds, eval_seed(cfg), args.max_steps)
        yield run, state, agent, traj


def cmd_mi(runs: list[Run], out: Path, args) -> list[Path]:
    """I(z; s) and I(z; s_j) (KSG, PCA to ``--pca`` components) of each agent."""
    one_task(runs, "mi")
    rng = np.random.default_rng(args.seed)
    results = {}
    for run, _, _, traj in agent_runs(runs, args):
        live = traj.live.reshape(-1)
        z = traj.z.reshape(-1, traj.z.shape[-1])[live].numpy()
        s = traj.state.reshape(-1, traj.state.shape[-1])[live].numpy()
        if len(z) < args.samples:
            raise ValueError(
                f"{run.path}: {len(z)} steps collected, fewer than --samples {args.samples}; raise --worlds"
            )
        pick = rng.choice(len(z), args.samples, replace=False)
        joint, marginal = latent_state_information(z[pick], s[pick], args.pca, args.k, args.seed)
        results[run.label] = (joint, marginal)
        names = traj.state_names
        print(f"{run.label}: I(z; s) = {joint:.3f} nats")
    labels = list(results)
    width = 0.8 / len(labels)
    n_state = len(names)
    fig, (ax0, ax1) = plt.subplots(
        1, 2, figsize=(3 + 0.5 * n_state + 2, 3.8), gridspec_kw={"width_ratios": [1, 3]}
    )
    ax0.bar(range(len(labels)), [results[k][0] for k in labels], color=[f"C{i}" for i in range(len(labels))])
    ax0.set_xticks(range(len(labels)), labels, rotation=30, ha="right")
    ax0.set(title="I(z; s)", ylabel="nats")
    for i, label in enumerate(labels):
        ax1.bar(np.arange(n_state) + i * width, results[label][1], width, label=label, color=f"C{i}")
    ax1.set(title="I(z; s_j) per state element", ylabel="nats")
    ax1.set_xticks(np.arange(n_state) + 0.4 - width / 2, names, rotation=60, ha="right", fontsize=8)
    ax1.legend(fontsize=7)
    rows = [[label, "joint", results[label][0]] for label in labels]
    rows += [[label, name, v] for label in labels for name, v in zip(names, results[label][1], strict=True)]
    return [save_figure(fig, out / "mi.png"), write_csv(out / "mi.csv", ["run", "state", "mi_nats"], rows)]


def cmd_latent(runs: list[Run], out: Path, args) -> list[Path]:
    """2-component PCA of z over world 0's episode, coloured by time and by summed contacts."""
    written = []
    for run, _, _, traj in agent_runs(runs, args):
        steps = int(traj.live[:, 0].sum())
        z = traj.z[:steps, 0].numpy()
        contacts = traj.contacts[:steps, 0].sum(-1).numpy()
        scores, explained = pca(z, 2)
        fig, axes = plt.subplots(1, 2, figsize=(10, 4.2))
        for ax, colour, name in (
            (axes[0], np.arange(steps), "time step"),
            (axes[1], contacts, "summed contacts"),
        ):
            ax.plot(scores[:, 0], scores[:, 1], color="grey", linewidth=0.5, alpha=0.5)
            points = ax.scatter(scores[:, 0], scores[:, 1], c=colour, s=8, cmap="viridis")
            fig.colorbar(points, ax=ax, label=name)
            ax.set(xlabel=f"PC 1 ({explained[0]:.0%})", ylabel=f"PC 2 ({explained[1]:.0%})")
        fig.suptitle(f"{run.label}: latent trajectory of one episode")
        stem = f"latent-{run.exp_name}-{run.path.name}"
        written.append(save_figure(fig, out / f"{stem}.png"))
        rows = [[t, scores[t, 0], scores[t, 1], int(contacts[t])] for t in range(steps)]
        written.append(write_csv(out / f"{stem}.csv", ["step", "pc1", "pc2", "contacts"], rows))
    return written


def cmd_tactile(runs: list[Run], out: Path, args) -> list[Path]:
    """Predicted vs actual contacts over a sequence, and the confusion metrics per horizon."""
    written = []
    for run in runs:  # all checked before any is run
        if run.config["ssl"]["name"] not in ("tr", "tfd"):
            raise ValueError(
                f"tactile needs a TR or TFD run (ssl tr/tfd); {run.path} has ssl={run.config['ssl']['name']}"
            )
    for run, state, agent, traj in agent_runs(runs, args):
        ssl = run.config["ssl"]["name"]
        cfg = state["config"].copy()
        cfg.device = "cpu"
        env = make_eval_env(cfg, 1)
        loss = make_aux_update(cfg, agent, env).loss
        env.close()
        loss.load_state_dict(state["aux"]["loss"])
        steps = min(int(traj.live[:, 0].sum()), args.steps)
        episode = traj.inputs[:steps, 0]
        n_contacts = traj.contacts.shape[-1]
        if ssl == "tr":
            predicted = loss.predict_tactile(episode)[:, -n_contacts:]
            actual, first = traj.contacts[:steps, 0], 0
        else:  # one step ahead from every step: windows (t, t+1)
            windows = torch.stack([episode[:-1], episode[1:]], dim=1)
            predicted = loss.predict_tactile(windows)[:, 0, -n_contacts:]
            actual, first = traj.contacts[1:steps, 0], 1
        stem = f"tactile-{run.exp_name}-{run.path.name}"
        figure = contact_map(actual.numpy(), predicted.numpy(), first, run.label, ssl)
        written.append(save_figure(figure, out / f"{stem}.png"))
        rows = [
            [first + t, c, int(actual[t, c]), float(predicted[t, c])]
            for t in range(len(actual))
            for c in range(n_contacts)
        ]
        written.append(write_csv(out / f"{stem}.csv", ["step", "sensor", "actual", "predicted"], rows))
        written += confusion_over_training(run, out)
    return written


def contact_map(actual: np.ndarray, predicted: np.ndarray, first: int, title: str, ssl: str):
    """Sensors × time: actual contacts (black) above predicted probabilities (opacity)."""
    steps, sensors = actual.shape
    fig, axes = plt.subplots(2, 1, figsize=(max(6, steps / 12), 1.2 + 0.25 * sensors * 2), sharex=True)
    extent = (first - 0.5, first + steps - 0.5, sensors - 0.5, -0.5)
    axes[0].imshow(
        actual.T, aspect="auto", cmap="Greys", vmin=0, vmax=1, extent=extent, interpolation="nearest"
    )
    axes[0].set(ylabel="sensor", title="actual contacts")
    rgba = np.zeros((sensors, steps, 4))
    rgba[..., 2] = 0.8
    rgba[..., 3] = predicted.T
    axes[1].imshow(rgba, aspect="auto", extent=extent, interpolation="nearest")
    what = "reconstructed" if ssl == "tr" else "predicted one step ahead"
    axes[1].set(ylabel="sensor", xlabel="time step", title=f"{what} (opacity = probability)")
    fig.suptitle(title)
    return fig


def confusion_over_training(run: Run, out: Path) -> list[Path]:
    """TPR, FPR, FNR, TNR, accuracy and precision per horizon against frames, from the means per
    iteration that ``train.csv`` holds (``aux/<name>``)."""
    train = read_csv(run.path / "train.csv") if (run.path / "train.csv").is_file() else {}
    aux = {k.removeprefix("aux/"): v for k, v in train.items() if k.startswith("aux/") or k == "frames"}
    if not any(k.startswith(CONFUSION) for k in aux):
        print(f"{run.path}: its train.csv holds no confusion metrics of the auxiliary objective")
        return []
    frames = np.asarray(aux["frames"])
    steps = sorted({f for f in frames})
    fig, axes = plt.subplots(1, len(CONFUSION), figsize=(3.2 * len(CONFUSION), 3.2))
    rows = []
    for ax, name in zip(axes, CONFUSION, strict=True):
        columns = [k for k in aux if k == name or k.startswith(f"{name}_h")]
        for column in columns:
            values = np.asarray(aux[column])
            per_iteration = [float(np.nanmean(values[frames == f])) for f in steps]
            ax.plot(steps, per_iteration, label=column.removeprefix(name).lstrip("_") or "reconstruction")
            rows += [[column, int(f), v] for f, v in zip(steps, per_iteration, strict=True)]
        ax.set(title=name, xlabel="frames", ylim=(0, 1))
    axes[0].legend(fontsize=7)
    stem = f"tactile-metrics-{run.exp_name}-{run.path.name}"
    return [
        save_figure(fig, out / f"{stem}.png"),
        write_csv(out / f"{stem}.csv", ["metric", "frames", "mean"], rows),
    ]


# ---------------------------------------------------------------------------- auxiliary memory


def cmd_aux_memory(runs: list[Run], out: Path, args) -> list[Path]:
    """The unscaled auxiliary loss of every minibatch over training, one line per run (from
    ``aux.csv``: runs trained with ``logger.aux_minibatches=true``)."""
    fig, ax = plt.subplots(figsize=(8, 4))
    rows = []
    for run in runs:
        needs = "aux-memory needs runs with an SSL objective trained with logger.aux_minibatches=true"
        aux = run_csv(run, "aux.csv", needs)
        terms = [k for k in aux if k.startswith("loss_")]
        loss = np.sum([np.asarray(aux[k]) for k in terms], axis=0)
        memory = run.config["ssl"]["memory_rollouts"]
        ax.plot(np.arange(len(loss)), loss, linewidth=0.6, label=f"{run.label} (N_rollouts={memory})")
        rows += [
            [run.label, memory, i, int(f), v]
            for i, (f, v) in enumerate(zip(aux["frames"], loss, strict=True))
        ]
    ax.set(xlabel="auxiliary step (minibatch)", ylabel="auxiliary loss (unscaled)", yscale="log")
    ax.set_title("auxiliary loss per minibatch")
    ax.legend(fontsize=7)
    header = ["run", "memory_rollouts", "step", "frames", "loss"]
    return [save_figure(fig, out / "aux_memory.png"), write_csv(out / "aux_memory.csv", header, rows)]


# ---------------------------------------------------------------------------- the results table


def cmd_table(runs: list[Run], out: Path, args) -> list[Path]:
    """The results table: physical metrics and return per experiment, mean and max over seeds."""
    at = parse_frames(args.at) if args.at else []
    rows = results_table(runs, at, load_reference() if args.reference else None)
    markdown = table_markdown(rows, args.reference)
    print(markdown)
    (out / "table.md").write_text(markdown)
    return [out / "table.md", write_table_csv(rows, out / "table.csv", args.reference)]


def cmd_stability(runs: list[Run], out: Path, args) -> list[Path]:
    """Per run: training episodes at frame marks, best and final evaluation of the task's metric,
    median KL and clip fraction."""
    marks = parse_frames(args.at) if args.at else default_marks(runs)
    rows = [run_stability(run, marks, args.metric) for run in runs]
    markdown = stability_markdown(rows, marks)
    print(markdown)
    (out / "stability.md").write_text(markdown)
    header, csv_rows = stability_csv_rows(rows, marks)
    return [out / "stability.md", write_csv(out / "stability.csv", header, csv_rows)]


def cmd_episodes(runs: list[Run], out: Path, args) -> list[Path]:
    """Per run, window by window: the training episodes (the sampled policy) beside the
    evaluations (the deterministic controller), for every metric both log."""
    every = parse_frames(args.every)[0]
    metrics = args.metric.split(",") if args.metric else None
    sections, headers, rows = [], set(), []
    for run in runs:
        names, windows = run_windows(run, every, metrics)
        sections.append(windows_markdown(run.label, names, windows))
        header, run_rows = windows_csv_rows(run.label, names, windows)
        headers.add(tuple(header))
        rows += run_rows
    if len(headers) > 1:  # one CSV, one set of columns
        raise ValueError("these runs log different metrics; give the ones to show with --metric")
    markdown = "\n".join(sections)
    print(markdown)
    (out / "episodes.md").write_text(markdown)
    return [out / "episodes.md", write_csv(out / "episodes.csv", list(headers.pop()), rows)]


def cmd_compare(runs: list[Run], out: Path, args) -> list[Path]:
    """The runs against the --against runs, paired by seed: finals, their paired difference and
    its standard error, holding, frames/s."""
    base = countable(find_runs(args.against), "compare", unfinished=args.unfinished)
    one_task(runs + base, "compare")
    comparison = compare_runs(base, runs, args.metric)
    markdown = comparison_markdown(comparison)
    print(markdown)
    (out / "compare.md").write_text(markdown)
    header, csv_rows = comparison_csv_rows(comparison)
    return [out / "compare.md", write_csv(out / "compare.csv", header, csv_rows)]


def cmd_study(runs: list[Run], out: Path, args) -> list[Path]:
    """A task's study: final policies scored alike, IQM and probability of improvement with
    intervals (rliable), performance profiles, curves beside the authors', the paper's claims."""
    from roto_trl.analysis.study import REPS, score_run, write_study

    task = one_task(runs, "study")
    if args.score:
        for run in runs:
            for path in score_run(run.path, args.episodes, mi=not args.no_mi):
                print(f"scored: {path}", flush=True)
    print(f"analyse study: {len(runs)} runs of {task}, each interval from {REPS:,} bootstrap resamples "
          "(a few minutes)", flush=True)  # fmt: skip
    return write_study(runs, task, out)


COMMANDS = {
    "curves": cmd_curves,
    "mi": cmd_mi,
    "latent": cmd_latent,
    "tactile": cmd_tactile,
    "aux-memory": cmd_aux_memory,
    "table": cmd_table,
    "stability": cmd_stability,
    "episodes": cmd_episodes,
    "compare": cmd_compare,
    "study": cmd_study,
}


COUNTING = ("curves", "table", "stability", "compare", "study")  # the commands that count runs over seeds


def positive_int(text: str) -> int:
    """An argparse type: an integer >= 1 (argparse names the option in its one-line error)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="analyse.py", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for name, fn in COMMANDS.items():
        p = sub.add_parser(name, help=fn.__doc__.splitlines()[0])
        p.add_argument("runs", nargs="+", help="run directories or quoted globs")
        p.add_argument(
            "--out", type=Path, default=None, help=f"output directory (default runs/analysis/{name})"
        )
        if name in COUNTING:
            p.add_argument(
                "--unfinished", action="store_true", help="count runs still going (or stopped early) too"
            )
        if name in ("mi", "latent", "tactile"):
            p.add_argument("--checkpoint", default="best", choices=["best", "latest"])
            p.add_argument(
                "--worlds", type=positive_int, default=100 if name == "mi" else 1, help="evaluation episodes"
            )
            p.add_argument(
                "--max-steps", type=positive_int, default=None, help="steps per episode (default: all)"
            )
        if name == "curves":
            p.add_argument(
                "--no-physical", action="store_true", help="skip the physical-metric bars (no eval.json)"
            )
            p.add_argument("--x", choices=["frames", "minutes"], default="frames", help="curves against")
            p.add_argument(
                "--metric",
                help="the eval.csv column to plot (default: the task's headline metric, e.g. reached_3cm)",
            )
        if name == "mi":
            p.add_argument(
                "--samples", type=positive_int, default=5000, help="(z, s) pairs, drawn from all steps"
            )
            p.add_argument("--pca", type=positive_int, default=13, help="principal components of z")
            p.add_argument("--k", type=positive_int, default=4, help="KSG neighbours")
            p.add_argument("--seed", type=int, default=0, help="seed of the sample draw")
        if name == "tactile":
            p.add_argument("--steps", type=positive_int, default=120, help="steps shown in the contact map")
        if name == "table":
            p.add_argument("--at", default=None, help="also at these frame counts, e.g. 2.5M,5M,10M")
            p.add_argument("--reference", action="store_true", help="the authors' numbers beside ours")
        if name in ("stability", "compare"):
            p.add_argument(
                "--metric",
                default=None,
                help="an eval.csv column, e.g. return_mean (default: the task's headline metric)",
            )
        if name == "episodes":
            p.add_argument("--every", default="1M", help="the windows' width in frames, e.g. 500k or 1M")
            p.add_argument(
                "--metric",
                default=None,
                help="eval.csv columns, comma-separated (default: every one the training episodes log too)",
            )
        if name == "compare":
            p.add_argument(
                "--against",
                nargs="+",
                required=True,
                help="the base runs (directories or quoted globs), same seeds",
            )
        if name == "study":
            p.add_argument("--score", action="store_true", help="first score the runs not yet scored")
            p.add_argument("--episodes", type=positive_int, default=1000, help="scoring episodes per run")
            p.add_argument("--no-mi", action="store_true", help="score without the mutual information")
        if name == "stability":
            p.add_argument(
                "--at",
                default=None,
                help="frame marks of the training episodes (default: 15, 25, 50, 75, 100 %% of the budget)",
            )
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> list[Path]:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    out = args.out or Path("runs") / "analysis" / args.command
    try:
        runs = find_runs(args.runs)
        if args.command in COUNTING:  # a table or figure over seeds: only runs it can count
            runs = countable(runs, args.command, unfinished=args.unfinished)
        out.mkdir(parents=True, exist_ok=True)
        written = COMMANDS[args.command](runs, out, args)
    except (ValueError, FileNotFoundError) as err:  # bad input: one line, no traceback
        raise SystemExit(f"analyse {args.command}: {err}") from None
    for path in written:
        print(path.resolve())
    return written


if __name__ == "__main__":
    main()
