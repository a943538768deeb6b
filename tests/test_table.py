"""``analyse.py table``: each experiment's metrics over seeds at the final evaluation and at chosen
frame counts, and the authors' numbers beside them; checked on hand-written runs."""

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from headline_figure import main as headline_main
from headline_figure import seed_band

from roto_trl import analyse
from roto_trl.analysis.episodes import run_windows
from roto_trl.analysis.runs import Run
from roto_trl.analysis.stability import best_evaluation, default_marks, training_at
from roto_trl.analysis.table import frames_label, load_reference, parse_frames, table_metric

M = 1_000_000
# exp_name, seed -> eval.csv columns (bounces is a per-episode mean the table leaves out)
EVALS = {
    ("bounce_ppo", 0): {
        "frames": [0, 1 * M, 2 * M, 5 * M],
        "return_mean": [0, 2, 4, 10],
        "bpt": [0, 1, 2, 5],
    },
    ("bounce_ppo", 1): {
        "frames": [0, 1 * M, 2 * M, 5 * M],
        "return_mean": [0, 4, 6, 12],
        "bpt": [0, 3, 4, 7],
    },
    ("bounce_fd", 0): {
        "frames": [0, 2 * M, 4 * M, 6 * M],
        "return_mean": [0, 8, 12, 20],
        "bpt": [0, 2, 6, 9],
    },
    ("bounce_fd", 1): {
        "frames": [0, 2 * M, 4 * M],
        "return_mean": [0, 4, 10],
        "bpt": [0, 1, 3],
    },  # stopped early
}


def write_runs(root: Path) -> None:
    root.mkdir(parents=True)
    (root / "multirun.yaml").write_text("hydra: {}\n")  # what Hydra leaves in a sweep directory: no run
    for (exp, seed), columns in EVALS.items():
        run = root / f"{exp}-s{seed}"
        run.mkdir()
        budget = 6 * M if exp == "bounce_fd" else 5 * M
        config = f"exp_name: {exp}\nseed: {seed}\ntotal_frames: {budget}\nenv:\n  task: bounce\n"
        (run / "config.yaml").write_text(config)
        if columns["frames"][-1] >= budget:  # finished: summary.json written
            (run / "summary.json").write_text("{}")
        with (run / "eval.csv").open("w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(["frames", "return_mean", "return_std", "bounces", "bounces_per_10s"])
            for frames, ret, per_10s in zip(
                columns["frames"], columns["return_mean"], columns["bpt"], strict=True
            ):
                writer.writerow([frames, ret, 0.5, per_10s, per_10s])


def read(path: Path) -> dict[tuple[str, str, str], dict[str, str]]:
    with path.open(newline="") as handle:
        return {(r["exp_name"], r["at"], r["metric"]): r for r in csv.DictReader(handle)}


def test_table_of_two_experiments_with_two_seeds(tmp_path, capsys):
    write_runs(tmp_path / "runs")
    out = tmp_path / "table"
    runs = str(tmp_path / "runs" / "*")
    analyse.main(["table", runs, "--at", "1.5M,5M", "--reference", "--out", str(out), "--unfinished"])
    rows = read(out / "table.csv")
    # 2 experiments x 3 points (final, 1.5M, 5M) x 2 metrics (return, bounces_per_10s)
    assert len(rows) == 12

    def check(exp, at, metric, frames, seeds, mean, mx):
        row = rows[(exp, at, metric)]
        assert (int(row["frames"]), int(row["seeds"])) == (frames, seeds)
        assert (float(row["mean"]), float(row["max"])) == pytest.approx((mean, mx))
        return row

    # final: each run's last evaluation; frames the runs' mean (fd: 6M and 4M)
    check("bounce_ppo", "final", "return", 5 * M, 2, (10 + 12) / 2, 12)
    check("bounce_ppo", "final", "bounces_per_10s", 5 * M, 2, (5 + 7) / 2, 7)
    check("bounce_fd", "final", "return", 5 * M, 2, (20 + 10) / 2, 20)
    check("bounce_fd", "final", "bounces_per_10s", 5 * M, 2, (9 + 3) / 2, 9)
    # 1.5M: halfway between the evaluations at 1M and 2M (ppo), 3/4 of the way from 0 to 2M (fd)
    check("bounce_ppo", "1.5M", "return", 1.5 * M, 2, (3 + 5) / 2, 5)
    check("bounce_ppo", "1.5M", "bounces_per_10s", 1.5 * M, 2, (1.5 + 3.5) / 2, 3.5)
    check("bounce_fd", "1.5M", "return", 1.5 * M, 2, (6 + 3) / 2, 6)
    check("bounce_fd", "1.5M", "bounces_per_10s", 1.5 * M, 2, (1.5 + 0.75) / 2, 1.5)
    # 5M: fd seed 1 ended at 4M and does not count; fd seed 0 halfway between 4M and 6M
    check("bounce_ppo", "5M", "return", 5 * M, 2, 11, 12)
    check("bounce_fd", "5M", "return", 5 * M, 1, 16, 16)
    fd_5m = check("bounce_fd", "5M", "bounces_per_10s", 5 * M, 1, 7.5, 7.5)
    # the authors' numbers: at exactly 5M, and at their final evaluation (200M) beside our final
    assert (fd_5m["ref_frames"], fd_5m["ref_mean"], fd_5m["ref_max"], fd_5m["ref_seeds"]) == (
        "5000000",
        "1.646",
        "5.223",
        "5",
    )
    final = rows[("bounce_fd", "final", "bounces_per_10s")]
    assert (final["ref_frames"], final["ref_mean"], final["ref_max"]) == ("200000000", "69.87", "75.7")
    assert rows[("bounce_ppo", "1.5M", "return")]["ref_mean"] == ""  # they kept no evaluation at 1.5M

    markdown = (out / "table.md").read_text()
    assert markdown in capsys.readouterr().out
    assert "| bounce_fd | 5M | ours | 5M | 1 | 16 / 16 | 7.5 / 7.5 |" in markdown
    assert "| | | authors | 5M | 5 | 27.8 / 113 | 1.65 / 5.22 |" in markdown
    assert markdown.startswith("## bounce\n")


def test_table_without_reference_has_no_reference_columns(tmp_path):
    write_runs(tmp_path / "runs")
    analyse.main(["table", str(tmp_path / "runs" / "bounce_ppo-*"), "--out", str(tmp_path / "t")])
    rows = read(tmp_path / "t" / "table.csv")
    assert sorted(rows) == [("bounce_ppo", "final", "bounces_per_10s"), ("bounce_ppo", "final", "return")]
    assert "ref_mean" not in next(iter(rows.values()))
    assert "authors" not in (tmp_path / "t" / "table.md").read_text()


def test_frame_counts_and_metric_names():
    assert parse_frames("2M,5M,10M") == [2 * M, 5 * M, 10 * M]
    assert parse_frames("2.5M, 500k,1000,1e6") == [2_500_000, 500_000, 1000, M]
    for bad in ("2X", "-1M", "0", "", "M"):
        with pytest.raises(ValueError, match="--at"):
            parse_frames(bad)
    assert [frames_label(f) for f in (2_500_000, 400_000, 5 * M, 999)] == ["2.5M", "400k", "5M", "999"]
    assert table_metric("return_mean") == "return" and table_metric("return_std") is None
    assert table_metric("find_time_1cm") == "find_time_1cm_s" and table_metric("reached_1cm") == "reached_1cm"
    assert table_metric("rotations_per_10s") == "rotations_per_10s" and table_metric("bounces") is None


def test_reference_file_ships_every_experiment():
    reference = load_reference()
    for task, metric in (
        ("find", "reached_1cm"),
        ("bounce", "bounces_per_10s"),
        ("baoding", "rotations_per_10s"),
    ):
        for variant in ("ppo_prop", "ppo", "fr", "tr", "fd", "tfd", "fd_mem", "ppo_prop_nolastaction"):
            curve = reference[(f"{task}_{variant}", metric)]
            assert max(curve) == 200 * M and 2_500_000 in curve


def test_table_rejects_bad_input_with_one_line(tmp_path):
    write_runs(tmp_path / "runs")
    with pytest.raises(
        SystemExit, match=r"^analyse table: --at must be a positive whole number of frames .* got '5Q'"
    ):
        analyse.main(["table", str(tmp_path / "runs" / "*"), "--at", "5Q", "--out", str(tmp_path / "t")])
    (tmp_path / "runs" / "bounce_fd-s0" / "eval.csv").unlink()
    (tmp_path / "runs" / "bounce_ppo-s0" / "eval.csv").unlink()
    (tmp_path / "runs" / "bounce_ppo-s1" / "eval.csv").unlink()
    with pytest.raises(SystemExit, match=r"^analyse table: no run left to count"):
        analyse.main(["table", str(tmp_path / "runs" / "*"), "--out", str(tmp_path / "t")])


def test_the_best_evaluation_is_the_one_best_pt_holds():
    """Ranked as training ranks evaluations for best.pt: the metric, then the return on a tie (a
    Find fraction repeats often on 128 worlds), the earliest of exact ties, NaN last."""
    metric = np.array([0.25, 0.5, 0.5, np.nan, 0.5])
    assert best_evaluation(metric, [90.0, 100.0, 120.0, 500.0, 110.0], "reached_3cm") == 2
    assert best_evaluation(metric, [90.0, 100.0, 100.0, 500.0, 100.0], "reached_3cm") == 1
    assert best_evaluation(metric, None, "reached_3cm") == 1  # logs without returns: the metric alone


def test_stability_rows_by_hand(tmp_path, capsys):
    run = tmp_path / "bounce_ppo-s3"
    run.mkdir()
    (run / "config.yaml").write_text(
        "exp_name: bounce_ppo\nseed: 3\ntotal_frames: 200\nenv:\n  task: bounce\n"
    )
    (run / "summary.json").write_text("{}")
    (run / "eval.csv").write_text("frames,return_mean,bounces_per_10s\n0,0.1,0\n100,50,10\n200,40,7\n")
    # the per-iteration medians: KL 0.01, 0.03, (empty), 0.02 -> 0.02; clip 0.1, 0.3, 0.2 -> 0.2;
    # training episodes: 2 ended with 1 bounce at 50, none at 100, 1 with 4 at 150, 3 with 8 at 200
    (run / "train.csv").write_text(
        "frames,fps,kl_k3_median,clip_fraction_median,episodes,episode/bounces\n"
        "50,900,0.01,0.1,2,1\n100,1000,0.03,0.3,,\n150,1100,,,1,4\n200,1200,0.02,0.2,3,8\n"
    )
    (run / "eval.json").write_text('{"episodes": 100, "physical": {"bounces_per_10s": 9.5}}')
    out = tmp_path / "stability"
    analyse.main(["stability", str(run), "--out", str(out), "--at", "100,200,300"])
    with (out / "stability.csv").open(newline="") as handle:
        (row,) = list(csv.DictReader(handle))
    # windows of 49,152 frames hold everything up to the mark: (2 x 1) / 2 and (2 + 4 + 24) / 6;
    # the log ends before 300
    assert float(row["training_100"]) == 1.0 and float(row["training_200"]) == 5.0
    assert math.isnan(float(row["training_300"]))
    # before the best evaluation (100) and the final one (200): the same windows
    assert (float(row["training_at_best"]), float(row["training_at_final"])) == (1.0, 5.0)
    assert (row["best"], row["best_frames"], row["final"]) == ("10.0", "100", "7.0")
    assert float(row["held"]) == pytest.approx(0.7)  # under 0.8 of the best: flagged
    assert (float(row["kl_median"]), float(row["clip_median"])) == (0.02, 0.2)
    assert float(row["frames_per_s"]) == 1050
    assert (row["checkpoint_value"], row["checkpoint_episodes"]) == ("9.5", "100")
    assert row["final_checkpoint_value"] == "" and math.isnan(float(row["held_checkpoints"]))
    printed = capsys.readouterr().out
    assert "0.70 (fell back) | 1.00 / 5.00 |" in printed and "episode/bounces: 1.00 / 5.00 / –" in printed
    assert "| 9.5 (100) | – |" in printed
    # the final checkpoint re-evaluated like the best one: 7.7 / 9.5 = 0.81 holds, 7.5 (0.79) falls back
    made = {"episodes": 100, "seed": 1, "policy": "applied_mean"}
    (run / "eval.json").write_text(json.dumps({**made, "physical": {"bounces_per_10s": 9.5}}))
    for value, printed_cell in ((7.7, "| 7.7, 0.81 |"), (7.5, "| 7.5, 0.79 (fell back) |")):
        (run / "eval-latest.json").write_text(json.dumps({**made, "physical": {"bounces_per_10s": value}}))
        analyse.main(["stability", str(run), "--out", str(out), "--at", "100,200"])
        with (out / "stability.csv").open(newline="") as handle:
            (row,) = list(csv.DictReader(handle))
        assert float(row["held_checkpoints"]) == pytest.approx(value / 9.5)
        assert printed_cell in capsys.readouterr().out
    # made otherwise (other episodes, or the sampled policy): not compared
    for other in ({"episodes": 200}, {"policy": "stochastic"}):
        latest = {**made, **other, "physical": {"bounces_per_10s": 7.7}}
        (run / "eval-latest.json").write_text(json.dumps(latest))
        analyse.main(["stability", str(run), "--out", str(out), "--at", "100,200"])
        with (out / "stability.csv").open(newline="") as handle:
            (row,) = list(csv.DictReader(handle))
        assert math.isnan(float(row["held_checkpoints"]))
    capsys.readouterr()
    (run / "eval-latest.json").unlink()
    # a log with the headline metric of the training episodes reads that, in the evaluation's unit
    (run / "train.csv").write_text(
        "frames,episodes,episode/bounces,episode/bounces_per_10s\n50,2,1,1.5\n200,2,8,12\n"
    )
    analyse.main(["stability", str(run), "--out", str(out), "--at", "100,200"])
    with (out / "stability.csv").open(newline="") as handle:
        (row,) = list(csv.DictReader(handle))
    assert (float(row["training_100"]), float(row["training_200"])) == (1.5, 6.75)
    assert "episode/bounces_per_10s: 1.50 / 6.75" in capsys.readouterr().out


def test_training_windows_by_hand():
    frames = np.array([100_000, 200_000, 250_000, 300_000])
    values = np.array([1.0, 2.0, np.nan, 6.0])
    episodes = np.array([10, 30, 0, 10])
    # window 150k before 300k: 200k (30 x 2) and 300k (10 x 6); 250k had no episode
    at = training_at(frames, values, episodes, [300_000, 100_000, 400_000], window=150_000)
    assert at[:2] == [pytest.approx(3.0), 1.0] and math.isnan(at[2])
    # a per-episode log whose last episode ended before the budget: ``until`` says what it covers
    assert training_at(frames, values, episodes, [400_000], window=150_000, until=400_000) == [6.0]


def test_episodes_windows_by_hand(tmp_path, capsys):
    run = tmp_path / "baoding_ppo-s3"
    run.mkdir()
    config = "exp_name: baoding_ppo\nseed: 3\ntotal_frames: 400\nenv:\n  task: baoding\n"
    (run / "config.yaml").write_text(config)
    # windows of 200 frames: (0, 200] and (200, 300], the log's end
    (run / "train.csv").write_text(
        "frames,episodes,episode_return,episode/turns,loss\n"
        "100,1,10,2.0,0.5\n200,3,30,0.0,0.5\n250,,,,0.5\n300,2,20,1.0,0.5\n"
    )
    (run / "eval.csv").write_text(
        "frames,return_mean,turns,latent_rank\n100,70,0.5,3\n200,80,0.0,3\n300,90,0.25,3\n"
    )
    out = tmp_path / "episodes"
    analyse.main(["episodes", str(run), "--every", "200", "--out", out.as_posix()])
    with (out / "episodes.csv").open(newline="") as handle:
        first, second = list(csv.DictReader(handle))
    # training episodes weighted by how many ended: (1 x 2.0 + 3 x 0.0) / 4; evaluations a plain mean
    train = [float(first["train_turns"]), float(first["train_return_mean"]), float(second["train_turns"])]
    assert train == [0.5, 25.0, 1.0] and (first["episodes"], second["episodes"]) == ("4", "2")
    evaluation = [float(first["eval_turns"]), float(first["eval_return_mean"]), float(second["eval_turns"])]
    assert evaluation == [0.25, 75.0, 0.25] and (first["evaluations"], second["evaluations"]) == ("2", "1")
    assert second["end"] == "300"
    assert "latent_rank" not in first  # not logged for the training episodes
    assert "| 0-200 | 4 | 25 | 0.5 | 2 | 75 | 0.25 |" in capsys.readouterr().out
    with pytest.raises(SystemExit, match=r"latent_rank is not logged for both .* from return_mean, turns$"):
        analyse.main(["episodes", str(run), "--metric", "latent_rank", "--out", out.as_posix()])


def test_episodes_a_sliver_past_the_budget_joins_the_last_window(tmp_path):
    # a run stops at the first iteration past its budget: 410 frames of a 400-frame budget
    run = tmp_path / "baoding_ppo-s3"
    run.mkdir()
    (run / "train.csv").write_text("frames,episodes,episode/turns\n200,1,1.0\n400,1,2.0\n410,2,4.0\n")
    (run / "eval.csv").write_text("frames,turns\n200,0.5\n410,1.5\n")
    _, windows = run_windows(Run(run, "baoding_ppo", "baoding", 3, {}), every=200)
    assert [(w.start, w.end, w.episodes) for w in windows] == [(0, 200, 1), (200, 410, 3)]
    assert windows[1].training["turns"] == pytest.approx((2.0 + 2 * 4.0) / 3)


def test_stability_marks_follow_the_budget():
    def run(budget):
        return Run(Path("r"), "baoding_ppo", "baoding", 0, {"total_frames": budget})

    assert default_marks([run(2_000_000)]) == [300_000, 500_000, 1_000_000, 1_500_000, 2_000_000]
    mixed = default_marks([run(2_000_000), run(10_000_000)])  # the largest budget's
    assert mixed == [1_500_000, 2_500_000, 5_000_000, 7_500_000, 10_000_000]


def test_headline_figure_bands_seeds_on_common_frames(tmp_path):
    short = {"frames": [0.0, 100.0, 200.0], "bounces_per_10s": [0.0, 2.0, 4.0]}
    long = {"frames": [0.0, 50.0, 250.0], "bounces_per_10s": [0.0, 5.0, 25.0]}
    frames, mean, low, high = seed_band([short, long], "bounces_per_10s")
    # up to the shorter run's last evaluation; the longer interpolated onto 100 and 200 (10, 20)
    assert frames.tolist() == [0.0, 50.0, 100.0, 200.0]
    assert mean.tolist() == [0.0, 3.0, 6.0, 12.0] and low.tolist() == [0.0, 1.0, 2.0, 4.0]
    assert high.tolist() == [0.0, 5.0, 10.0, 20.0]
    for seed, curve in enumerate((short, long)):
        run = tmp_path / f"bounce_ppo-s{seed}"
        run.mkdir()
        config = f"exp_name: bounce_ppo\nseed: {seed}\ntotal_frames: 200\nenv:\n  task: bounce\n"
        (run / "config.yaml").write_text(config)
        (run / "summary.json").write_text("{}")
        points = zip(curve["frames"], curve["bounces_per_10s"], strict=True)
        rows = "".join(f"{f},1.0,{v}\n" for f, v in points)
        (run / "eval.csv").write_text("frames,return_mean,bounces_per_10s\n" + rows)
    out = tmp_path / "headline.png"
    assert headline_main([str(tmp_path / "bounce_ppo-s*"), "--out", str(out)]) == 0
    assert out.stat().st_size > 10_000
