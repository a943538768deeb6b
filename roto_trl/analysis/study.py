"""The paper's study of one task: every variant over fresh seeds, scored alike, compared with the
field's statistics (rliable), and set beside the paper's claims.

A study directory holds one run per variant and seed (``python roto_trl/train.py +study=<task>``,
``conf/study/``). :func:`score_run` scores each finished run's final checkpoint on the same
``SCORE_EPISODES`` evaluation episodes with our evaluation action (``score.json``) and with the
authors' (the Gaussian's mean, ``score-gaussian_mean.json``), and the mutual information between
its latent and the task's state (``mi.json``: KSG on 5000 samples, PCA to 13 components, 4
neighbours, as the paper's Section 6). :func:`write_study` then writes, for the task's headline
metric: the interquartile mean of the final policies with 95 % stratified-bootstrap intervals,
the probability of improvement of each variant over PPO (prop-tactile), performance profiles,
IQM learning curves with their bands beside the authors' curves, and the claims table
(``CLAIMS``): for each claim, the comparison and a verdict from the interval of the probability
of improvement, given once each variant has ``VERDICT_SEEDS`` seeds.
"""

from __future__ import annotations

import csv
import json
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import scipy.stats
from rliable import library as rly
from rliable import metrics

from roto_trl.analysis.checkpoint_eval import evaluate_run, load_run
from roto_trl.analysis.metrics import describe
from roto_trl.analysis.mutual_information import latent_state_information
from roto_trl.analysis.plots import save_figure
from roto_trl.analysis.rollouts import collect
from roto_trl.analysis.runs import Run, headline_of
from roto_trl.analysis.table import load_reference
from roto_trl.trainers.builders import eval_seed
from roto_trl.trainers.loggers import read_csv

VARIANTS = ("ppo", "ppo_prop", "ppo_prop_nolastaction", "tr", "fr", "fd", "tfd", "fd_mem")
BASELINE = "ppo"  # PPO (prop-tactile): what the probability of improvement is over
SCORE_EPISODES = 1000
SCORES = {"ours": ("score.json", "deterministic"), "authors": ("score-gaussian_mean.json", "gaussian_mean")}
MI_FILE, MI_SAMPLES, MI_PCA, MI_K, MI_WORLDS = "mi.json", 5000, 13, 4, 32
REPS = 20_000  # bootstrap resamples of the intervals (rliable's default is 50,000; the CI moves by < 0.01)
# A verdict needs this many seeds of each variant: the fewest with which even a complete separation
# (every run of X above every run of Y) is told from chance at the 5 % level by the exact rank test
# (two-sided 2 / C(8, 4) = 0.029; with 3 seeds 2 / C(6, 3) = 0.10). With fewer, the bootstrap
# interval of P(X > Y) collapses onto 1.0 or 0.0 whenever the few runs separate, and would
# call a claim decided on two seeds.
VERDICT_SEEDS = 4
LOWER_IS_BETTER = ("find_time_",)  # metrics where less is better: compared the other way round
warnings.filterwarnings("ignore", category=FutureWarning, module="arch")  # rliable's RandomState


# -- scoring each run


def score_run(run_dir: Path, episodes: int = SCORE_EPISODES, mi: bool = True) -> list[Path]:
    """Score a finished run: its final checkpoint on ``episodes`` episodes with both evaluation
    actions, and the mutual information of its latent; what is already there is kept. Returns
    the files written."""
    run_dir = Path(run_dir)
    written = []
    for name, policy in SCORES.values():
        if not (run_dir / name).is_file():
            written.append(
                evaluate_run(run_dir, "latest", episodes=episodes, policy=policy, out=run_dir / name)
            )
    if mi and not (run_dir / MI_FILE).is_file():
        cfg, state, _ = load_run(run_dir, "latest")
        _, traj = collect(state, MI_WORLDS, eval_seed(cfg))
        live = traj.live.reshape(-1)
        z = traj.z.reshape(-1, traj.z.shape[-1])[live].numpy()
        s = traj.state.reshape(-1, traj.state.shape[-1])[live].numpy()
        pick = np.random.default_rng(0).choice(len(z), min(MI_SAMPLES, len(z)), replace=False)
        joint, marginal = latent_state_information(z[pick], s[pick], MI_PCA, MI_K, 0)
        result = {"joint": joint, "marginal": dict(zip(traj.state_names, map(float, marginal), strict=True))}
        (run_dir / MI_FILE).write_text(json.dumps({**result, "samples": len(pick)}, indent=2))
        written.append(run_dir / MI_FILE)
    return written


# -- what the study holds


def variant_of(run: Run, task: str) -> str | None:
    """The paper's variant of a run of ``task`` (its ``exp_name`` past ``<task>_``), or None."""
    variant = run.exp_name.removeprefix(f"{task}_")
    return variant if variant in VARIANTS and run.exp_name.startswith(task) else None


@dataclass
class VariantScores:
    """One variant's runs: the final policies' metrics on the scoring episodes, by action, and
    their evaluation curves."""

    variant: str
    seeds: list[int]
    final: dict[str, dict[str, np.ndarray]]  # action (ours, authors) -> metric -> [seeds]
    mi: np.ndarray  # [seeds] I(z; s), NaN where not scored
    frames: np.ndarray  # [F] the evaluations' common frames
    curve: np.ndarray  # [seeds, F] the headline metric during training


def gather(runs: list[Run], task: str, headline: str) -> dict[str, VariantScores]:
    """The study's runs by variant (runs of other experiments are left aside)."""
    by_variant: dict[str, list[Run]] = {}
    for run in runs:
        variant = variant_of(run, task)
        if variant is not None:
            by_variant.setdefault(variant, []).append(run)
    out = {}
    for variant in (v for v in VARIANTS if v in by_variant):
        members = sorted(by_variant[variant], key=lambda r: r.seed)
        final: dict[str, dict[str, list[float]]] = {}
        for action, (name, _) in SCORES.items():
            for run in members:
                scored = _json(run.path / name)
                values = {"return_mean": scored["return_mean"], **scored["physical"]} if scored else {}
                for metric, value in values.items():
                    final.setdefault(action, {}).setdefault(metric, []).append(float(value))
        mi = np.array([(_json(r.path / MI_FILE) or {"joint": math.nan})["joint"] for r in members], float)
        curves = [read_csv(r.path / "eval.csv") for r in members]
        end = min(c["frames"][-1] for c in curves)
        frames = np.unique(np.concatenate([[f for f in c["frames"] if f <= end] for c in curves]))
        curve = np.stack([np.interp(frames, c["frames"], c[headline]) for c in curves])
        out[variant] = VariantScores(
            variant,
            [r.seed for r in members],
            {a: {m: np.asarray(v) for m, v in ms.items()} for a, ms in final.items()},
            mi,
            frames,
            curve,
        )
    return out


def _json(path: Path) -> dict | None:
    return json.loads(path.read_text()) if path.is_file() else None


# -- statistics


def oriented(values: np.ndarray, metric: str) -> np.ndarray:
    """Values turned so that higher is better (a time to a tolerance is negated)."""
    return -values if metric.startswith(LOWER_IS_BETTER) else values


def iqm_interval(values: np.ndarray, seed: int = 0, reps: int = REPS) -> tuple[float, float, float]:
    """The interquartile mean over runs ``[R]`` and its 95 % bootstrap interval: a one-frame curve."""
    point, low, high = iqm_curve(values.reshape(-1, 1), seed, reps)
    return float(point[0]), float(low[0]), float(high[0])


def _iqm_per_frame(x: np.ndarray) -> np.ndarray:
    """The IQM of each frame's runs: ``x`` ``[runs, 1, F]`` -> ``[F]``."""
    return scipy.stats.trim_mean(x[:, 0, :], proportiontocut=0.25, axis=0)


def iqm_curve(
    curve: np.ndarray, seed: int = 0, reps: int = REPS
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A learning curve's IQM over runs at each frame and its 95 % band, from ``curve``
    ``[runs, F]``: each resample draws whole runs (rliable's curves), and all ``F`` frames'
    IQMs come from one vectorised trim per resample. Returns ``(points, lows, highs)``, each ``[F]``."""
    point, interval = rly.get_interval_estimates(
        {"x": curve[:, None, :]}, _iqm_per_frame, reps=reps, random_state=np.random.RandomState(seed)
    )
    return np.asarray(point["x"]), np.asarray(interval["x"][0]), np.asarray(interval["x"][1])


def improvement(x: np.ndarray, y: np.ndarray, seed: int = 0, reps: int = REPS) -> tuple[float, float, float]:
    """P(a run of X scores above a run of Y) (ties count half) and its 95 % bootstrap interval;
    both ``[R]``, higher better."""
    point, interval = rly.get_interval_estimates(
        {"x,y": (x.reshape(-1, 1), y.reshape(-1, 1))},
        metrics.probability_of_improvement,
        reps=reps,
        random_state=np.random.RandomState(seed),
    )
    low, high = np.ravel(interval["x,y"])
    return float(point["x,y"]), float(low), float(high)


def verdict(low: float, high: float, same: bool = False) -> str:
    """A claim's verdict from the interval of P(X > Y): ``supported`` when it lies above 0.5,
    ``contradicted`` below; a claim of no difference (``same``) is ``contradicted`` when the
    interval leaves 0.5 out. Otherwise ``not resolved`` with these seeds at this budget."""
    if same:
        return "contradicted" if low > 0.5 or high < 0.5 else "not resolved (no difference found)"
    if low > 0.5:
        return "supported"
    if high < 0.5:
        return "contradicted"
    return "not resolved"


@dataclass(frozen=True)
class Claim:
    """One claim of the paper: X compared with Y on ``metric`` (``headline``: the task's; ``mi``:
    I(z; s); or a physical metric), ``kind`` ``greater`` (X beats Y) or ``same`` (no difference);
    for ``task`` (``*``: every task)."""

    task: str
    statement: str
    x: str
    y: str
    metric: str = "headline"
    kind: str = "greater"


RL_ONLY, SSL, RECON, DYN, MEMORY, LATENT = (
    "(Sec. 5, RL-only)",
    "(Sec. 5, RL+SSL)",
    "(Sec. 6, reconstruction)",
    "(Sec. 6, dynamics)",
    "(Sec. 5, memory)",
    "(Sec. 6, App. H)",
)
CLAIMS = (
    Claim(
        "find",
        f"touch gives PPO the final performance of proprioception alone {RL_ONLY}",
        "ppo",
        "ppo_prop",
        kind="same",
    ),
    Claim(
        "find",
        f"the proprioceptive agent relies on the last action {RL_ONLY}",
        "ppo_prop",
        "ppo_prop_nolastaction",
    ),
    Claim("bounce", f"touch gives PPO superior returns to proprioception alone {RL_ONLY}", "ppo", "ppo_prop"),
    Claim(
        "bounce",
        f"PPO (prop) without the last action does worse {RL_ONLY}",
        "ppo_prop",
        "ppo_prop_nolastaction",
    ),
    Claim("*", f"TR outperforms RL-only {SSL}", "tr", "ppo"),
    Claim("*", f"FD outperforms RL-only {SSL}", "fd", "ppo"),
    Claim("*", f"FD beats TR, the other leading method {SSL}", "fd", "tr"),
    Claim("find", f"FR outperforms TR {RECON}", "fr", "tr"),
    Claim("bounce", f"FR and TR perform almost identically {RECON}", "fr", "tr", kind="same"),
    Claim("find", f"TFD shows a minor benefit over FD {DYN}", "tfd", "fd"),
    Claim("bounce", f"TFD performs worse than FD {DYN}", "fd", "tfd"),
    Claim("*", f"the separated memory has a minimal effect {MEMORY}", "fd_mem", "fd", kind="same"),
    Claim("*", f"SSL raises the mutual information between latent and state: FD {LATENT}", "fd", "ppo", "mi"),
    Claim("*", f"SSL raises the mutual information between latent and state: TR {LATENT}", "tr", "ppo", "mi"),
    Claim(
        "find",
        "FD reaches 1 cm sooner than RL-only: 1.4 s against 1.9 s (Sec. 5)",
        "fd",
        "ppo",
        "find_time_1cm",
    ),
    Claim(
        "bounce",
        "FD bounces more than RL-only: 79 against 69 per 10 s (Sec. 5)",
        "fd",
        "ppo",
        "bounces_per_10s",
    ),
)


def claim_rows(task: str, scores: dict[str, VariantScores], headline: str, reps: int = REPS) -> list[dict]:
    """The claims of the paper about ``task``, each with our comparison and verdict: a claim on a
    policy's metric once per evaluation action (ours, and the authors' behind the paper's
    numbers: they can disagree), a claim on the MI once (``action`` empty)."""
    rows = []
    for claim in CLAIMS:
        if claim.task not in ("*", task):
            continue
        metric = headline if claim.metric == "headline" else claim.metric
        for action in ("",) if metric == "mi" else tuple(SCORES):
            row = {"claim": claim.statement, "x": claim.x, "y": claim.y, "metric": metric, "action": action}
            values = []
            for variant in (claim.x, claim.y):
                if variant not in scores:
                    values.append(None)
                elif metric == "mi":
                    values.append(scores[variant].mi)
                else:
                    values.append(scores[variant].final.get(action, {}).get(metric))
            if any(v is None or not np.isfinite(v).all() or len(v) < 2 for v in values):
                rows.append({**row, "verdict": "not yet measured"})
                continue
            a, b = (oriented(v, metric) for v in values)
            p, low, high = improvement(a, b, reps=reps)
            seeds = min(len(a), len(b))
            judged = (
                verdict(low, high, claim.kind == "same")
                if seeds >= VERDICT_SEEDS
                else f"not resolved ({seeds} seeds; a verdict needs {VERDICT_SEEDS})"
            )
            rows.append({**row, "poi": p, "poi_low": low, "poi_high": high, "verdict": judged})
    return rows


# -- writing the study


def write_study(runs: list[Run], task: str, out: Path) -> list[Path]:
    """Tables (Markdown and CSV) and figures of a task's study into ``out``; returns the files."""
    out.mkdir(parents=True, exist_ok=True)
    headline = headline_of(runs[0].path)
    scores = gather(runs, task, headline)
    if not scores:
        raise ValueError(f"no run of a {task} variant ({', '.join(VARIANTS)}) among the runs given")
    reference = load_reference()
    written = []
    rows = []
    for variant, s in scores.items():
        for action in SCORES:
            finals = s.final.get(action, {}).get(headline)
            if finals is None:
                continue
            point, low, high = iqm_interval(finals)
            rows.append({"variant": variant, "action": action, "metric": headline, "seeds": len(finals),
                         "iqm": point, "iqm_low": low, "iqm_high": high})  # fmt: skip
            if (
                variant != BASELINE
                and BASELINE in scores
                and headline in scores[BASELINE].final.get(action, {})
            ):
                base = scores[BASELINE].final[action][headline]
                rows[-1]["poi_over_ppo"], rows[-1]["poi_low"], rows[-1]["poi_high"] = improvement(
                    oriented(finals, headline), oriented(base, headline)
                )
    written.append(_write_csv(out / "final.csv", rows))
    claims = claim_rows(task, scores, headline)
    written.append(_write_csv(out / "claims.csv", claims))
    written.append(_curves_figure(scores, task, headline, reference, out / "curves.png"))
    written.append(_profiles_figure(scores, headline, out / "profiles.png"))
    scored = next(
        (_json(r.path / SCORES["ours"][0]) for r in runs if (r.path / SCORES["ours"][0]).is_file()), None
    )
    episodes = scored["episodes"] if scored else 0
    written.append(_markdown(task, scores, rows, claims, headline, reference, episodes, out / "study.md"))
    return written


def _write_csv(path: Path, rows: list[dict]) -> Path:
    header = list(dict.fromkeys(k for row in rows for k in row))
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=header)
        writer.writeheader()
        writer.writerows(rows)
    return path


def _curves_figure(scores, task, headline, reference, path: Path) -> Path:
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    for i, (variant, s) in enumerate(scores.items()):
        points, lows, highs = iqm_curve(s.curve)
        seeds = f"{len(s.seeds)} seed{'s' if len(s.seeds) > 1 else ''}"
        ax.plot(s.frames, points, color=f"C{i}", label=f"{variant} ({seeds})")
        ax.fill_between(s.frames, lows, highs, color=f"C{i}", alpha=0.15)
        theirs = reference.get((f"{task}_{variant}", headline), {})
        near = {f: v for f, v in theirs.items() if f <= 2 * s.frames[-1]}
        if near:
            ax.plot(list(near), [v[0] for v in near.values()], "x--", color=f"C{i}", linewidth=0.8)
    name, unit = describe(headline)
    ax.set(
        xlabel="frames",
        ylabel=unit or name,
        title=f"{task}: {name}, IQM and 95 % CI over seeds (x: the authors' mean)",
    )
    ax.legend(fontsize=7)
    return save_figure(fig, path)


def _profiles_figure(scores, headline, path: Path) -> Path:
    finals = {v: s.final["ours"][headline] for v, s in scores.items() if headline in s.final.get("ours", {})}
    fig, ax = plt.subplots(figsize=(6, 4))
    if finals:
        everything = np.concatenate(list(finals.values()))
        taus = np.linspace(everything.min(), everything.max(), 50)
        profiles, intervals = rly.create_performance_profile(
            {v: x.reshape(-1, 1) for v, x in finals.items()}, taus
        )
        for i, variant in enumerate(finals):
            ax.plot(taus, profiles[variant], color=f"C{i}", label=variant)
            ax.fill_between(taus, intervals[variant][0], intervals[variant][1], color=f"C{i}", alpha=0.15)
    name, unit = describe(headline)
    ax.set(
        xlabel=f"{name} ({unit})" if unit else name,
        ylabel="fraction of runs above",
        title="performance profiles",
    )
    ax.legend(fontsize=7)
    return save_figure(fig, path)


def _markdown(task, scores, rows, claims, headline, reference, episodes, path: Path) -> Path:
    name, unit = describe(headline)
    lines = [f"# The study on {task}", "", f"Headline metric: {name} ({unit}), final policies on "
             f"{episodes} episodes each (ours: our evaluation action; authors: the Gaussian's mean). "
             "IQM: interquartile mean over seeds, [95 % CI] by "
             "stratified bootstrap (rliable); P(> ppo): probability that a run of the variant beats "
             "a run of PPO (prop-tactile).", "",
             "| variant | action | seeds | IQM [95 % CI] | P(> ppo) [95 % CI] | the authors (nearest) |",
             "|---|---|---|---|---|---|"]  # fmt: skip
    for row in rows:
        theirs = reference.get((f"{task}_{row['variant']}", headline), {})
        frames = scores[row["variant"]].frames[-1]
        at = min(theirs, key=lambda f: abs(f - frames), default=None)
        authors = f"{theirs[at][0]:.3g} at {at / 1e6:g} M" if at else "–"
        poi = (
            f"{row['poi_over_ppo']:.2f} [{row['poi_low']:.2f}, {row['poi_high']:.2f}]"
            if "poi_over_ppo" in row
            else "–"
        )
        lines.append(f"| {row['variant']} | {row['action']} | {row['seeds']} | {row['iqm']:.3g} "
                     f"[{row['iqm_low']:.3g}, {row['iqm_high']:.3g}] | {poi} | {authors} |")  # fmt: skip
    lines += [
        "",
        "## The paper's claims",
        "",
        "| claim | comparison | action | P(X > Y) [95 % CI] | verdict |",
        "|---|---|---|---|---|",
    ]
    for c in claims:
        poi = f"{c['poi']:.2f} [{c['poi_low']:.2f}, {c['poi_high']:.2f}]" if "poi" in c else "–"
        action = c["action"] or "–"
        lines.append(
            f"| {c['claim']} | {c['x']} vs {c['y']} ({c['metric']}) | {action} | {poi} | {c['verdict']} |"
        )
    lines += ["", "![curves](curves.png)", "", "![profiles](profiles.png)", ""]
    path.write_text("\n".join(lines))
    return path
