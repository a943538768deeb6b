"""The study: the field's statistics by hand, the claims' verdicts, and a smoke-size study that runs,
skips what is finished and is analysed into tables and figures."""

import subprocess

import numpy as np
import pytest
from helpers import TRAIN
from hydra import compose, initialize_config_dir

from roto_trl.analysis.study import (
    VariantScores,
    claim_rows,
    improvement,
    iqm_curve,
    iqm_interval,
    oriented,
    verdict,
)
from roto_trl.trainers.provenance import read_provenance
from roto_trl.utils.resources import resource_dir


def test_iqm_and_probability_of_improvement_by_hand():
    # the IQM of 1..8 is the mean of the middle half, 3..6: 4.5
    point, low, high = iqm_interval(np.arange(1.0, 9.0), reps=500)
    assert point == pytest.approx(4.5) and low <= point <= high
    # every run of X above every run of Y: P = 1 with no room either way; equal runs: 0.5
    assert improvement(np.array([3.0, 4.0, 5.0]), np.array([0.0, 1.0, 2.0]), reps=500) == (1.0, 1.0, 1.0)
    assert improvement(np.ones(4), np.ones(4), reps=500) == (0.5, 0.5, 0.5)
    # X beats Y in 6 of the 9 pairs and ties in 2 (each counts half): (6 + 1) / 9
    p, _, _ = improvement(np.array([1.0, 2.0, 3.0]), np.array([1.0, 2.0, 0.0]), reps=500)
    assert p == pytest.approx(7 / 9)
    assert list(oriented(np.array([1.0, 2.0]), "find_time_1cm")) == [-1.0, -2.0]  # sooner is better


def test_a_curves_band_resamples_whole_runs_and_trims_each_frame():
    # frame 0: runs 1..8 (IQM 4.5, as above); frame 1: every run at 2.0, a band of no width;
    # frame 2: one outlying run of 100 among seven 1.0s is trimmed away, IQM 1.0
    curve = np.stack([np.arange(1.0, 9.0), np.full(8, 2.0), np.r_[np.ones(7), 100.0]], axis=1)
    points, lows, highs = iqm_curve(curve, reps=500)
    assert points == pytest.approx([4.5, 2.0, 1.0])
    assert lows[1] == highs[1] == 2.0
    assert np.all(lows <= points) and np.all(points <= highs) and highs[0] > lows[0]


def test_verdicts_from_the_interval():
    assert verdict(0.6, 0.9) == "supported" and verdict(0.1, 0.4) == "contradicted"
    assert verdict(0.4, 0.7) == "not resolved"
    assert verdict(0.4, 0.7, same=True) == "not resolved (no difference found)"
    assert verdict(0.55, 0.9, same=True) == "contradicted"


def test_a_claim_is_judged_under_each_evaluation_action_and_the_mi_once():
    def study(seeds):
        def scores(variant, ours, authors, mi):
            final = {"ours": {"bounces_per_10s": np.array(ours[:seeds])}}
            final["authors"] = {"bounces_per_10s": np.array(authors[:seeds])}
            return VariantScores(variant, [], final, np.array(mi[:seeds]), np.zeros(1), np.zeros((seeds, 1)))

        # FD beats PPO in every pair with our action and loses every pair with the authors'
        return {
            "ppo": scores("ppo", [10.0, 11.0, 12.0, 13.0], [9.0, 9.5, 10.0, 10.5], [1.0, 1.1, 1.2, 1.3]),
            "fd": scores("fd", [20.0, 21.0, 22.0, 23.0], [1.0, 2.0, 3.0, 4.0], [1.5, 1.6, 1.7, 1.8]),
        }

    def claims(seeds):
        return {
            (r["claim"], r["action"]): r
            for r in claim_rows("bounce", study(seeds), "bounces_per_10s", reps=500)
        }

    fd_over_ppo, fd_over_tr = (
        "FD outperforms RL-only (Sec. 5, RL+SSL)",
        "FD beats TR, the other leading method (Sec. 5, RL+SSL)",
    )
    rows = claims(4)
    # the same runs, opposite verdicts under the two actions; the MI has no action
    assert rows[(fd_over_ppo, "ours")]["verdict"] == "supported" and rows[(fd_over_ppo, "ours")]["poi"] == 1.0
    assert rows[(fd_over_ppo, "authors")]["verdict"] == "contradicted"
    mi_rows = [r for r in rows.values() if r["metric"] == "mi" and r["x"] == "fd"]
    assert [(r["action"], r["verdict"]) for r in mi_rows] == [("", "supported")]
    assert rows[(fd_over_tr, "ours")]["verdict"] == "not yet measured"  # no TR runs
    # the same complete separation on three seeds is no verdict: chance gives it 1 time in 10
    three = claims(3)[(fd_over_ppo, "ours")]
    assert three["poi"] == 1.0 and three["verdict"] == "not resolved (3 seeds; a verdict needs 4)"


@pytest.mark.parametrize("task", ["bounce", "find", "baoding"])
def test_a_study_goes_seed_by_seed_through_every_variant_of_its_task(task):
    with initialize_config_dir(str(resource_dir("conf")), version_base="1.3"):
        cfg = compose("train", overrides=[f"+study={task}"], return_hydra_config=True)
    params = cfg.hydra.sweeper.params
    assert list(params) == ["seed", "exp"]  # the product's first key varies slowest
    assert params.seed == "range(100,110)"
    variants = sorted(p.stem for p in (resource_dir("conf") / "exp").glob(f"{task}_*.yaml"))
    assert sorted(params.exp.split(",")) == variants and len(variants) == 8


@pytest.mark.slow  # end to end: a multirun of four runs, run twice, then scored and analysed
def test_a_study_runs_skips_what_is_finished_and_is_analysed(tmp_path):
    study = [
        "+study=find",
        'hydra.sweeper.params.exp="find_ppo,find_fd"',
        'hydra.sweeper.params.seed="100,101"',
        f"hydra.sweep.dir={tmp_path / 'study'}",
        *("env.num_envs=4", "total_frames=128", "agent.minibatches=2", "agent.epochs=1"),
        *("eval.num_envs=2", "eval.every_frames=64", "+env.overrides.episode_steps=20"),
    ]
    first = subprocess.run([*TRAIN, *study], capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr[-2000:]
    runs = sorted(p.name for p in (tmp_path / "study").iterdir() if p.is_dir())
    assert runs == ["find_fd-s100", "find_fd-s101", "find_ppo-s100", "find_ppo-s101"]
    # each job records its own overrides (its command line is the launcher's worker)
    job = read_provenance(tmp_path / "study" / "find_fd-s101")[0]["overrides"]
    assert {"+study=find", "seed=101", "exp=find_fd", "total_frames=128"} <= set(job)
    again = subprocess.run([*TRAIN, *study], capture_output=True, text=True, timeout=600)
    assert again.returncode == 0 and again.stdout.count("nothing to train, it is finished") == 4
    out = tmp_path / "out"
    analyse = [
        *TRAIN[:1],
        str(TRAIN[1]).replace("train.py", "analyse.py"),
        "study",
        str(tmp_path / "study" / "*"),
    ]
    done = subprocess.run(
        [*analyse, "--score", "--episodes", "4", "--out", str(out)], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-2000:]
    markdown = (out / "study.md").read_text()
    assert (
        "| fd | ours | 2 |" in markdown
        and "| FD outperforms RL-only (Sec. 5, RL+SSL) | fd vs ppo" in markdown
    )
    assert all((tmp_path / "study" / r / "score-gaussian_mean.json").is_file() for r in runs)
    assert (out / "curves.png").is_file() and (out / "profiles.png").is_file()
