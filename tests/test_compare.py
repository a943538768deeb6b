"""``analyse.py compare``: two sets of runs paired by seed, checked on hand-written runs."""

import csv
import json
import math

import pytest

from roto_trl import analyse
from roto_trl.analysis.compare import config_differences, paired_difference


def test_paired_difference_by_hand():
    # differences 2, 3, 0: mean 5/3; deviations 1/3, 4/3, -5/3 -> variance (1 + 16 + 25) / 9 / 2 = 7/3
    mean, standard_error = paired_difference([3, 5, 4], [1, 2, 4])
    assert mean == pytest.approx(5 / 3) and standard_error == pytest.approx(math.sqrt(7 / 3) / math.sqrt(3))
    assert paired_difference([2.0], [1.5])[0] == 0.5 and math.isnan(paired_difference([2.0], [1.5])[1])


def test_config_differences_name_the_choice_compared():
    def config(precision, lr, run_dir, seed):
        return {"agent": {"precision": precision, "lr": lr, "sizes": [64]}, "run_dir": run_dir, "seed": seed}

    base = [config("float32", 1e-3, "a", 0), config("float32", 2e-3, "b", 1)]
    test = [config("bfloat16", 1e-3, "c", 0), config("bfloat16", 2e-3, "d", 1)]
    # lr varies inside each set, run_dir and seed always differ: only the precision is the choice
    assert config_differences(base, test) == {"agent.precision": ("float32", "bfloat16")}
    test[0]["agent"]["weight_decay"] = 3.0  # a key that only the test set has, and not in all of it
    test[1]["agent"]["weight_decay"] = 3.0
    assert config_differences(base, test)["agent.weight_decay"] == (None, 3.0)


def write_run(root, name, seed, precision, evals, fps, best=None, latest=None):
    """A Bounce run: ``evals`` the in-run bounces per 10 s; ``best``/``latest`` its checkpoints'
    1000-episode re-evaluations."""
    run = root / name
    run.mkdir(parents=True)
    agent = f"agent:\n  precision: {precision}\n"
    (run / "config.yaml").write_text(
        f"exp_name: bounce_ppo\nseed: {seed}\ntotal_frames: {100 * len(evals)}\nrun_dir: {run}\n"
        f"{agent}env:\n  task: bounce\n"
    )
    (run / "summary.json").write_text("{}")
    rows = "".join(f"{100 * (i + 1)},{v},{v}\n" for i, v in enumerate(evals))
    (run / "eval.csv").write_text("frames,return_mean,bounces_per_10s\n" + rows)
    (run / "train.csv").write_text(f"frames,fps\n100,{fps}\n200,{fps}\n")
    made = {"episodes": 1000, "seed": 5, "policy": "applied_mean"}
    for file, value in (("eval.json", best), ("eval-latest.json", latest)):
        if value is not None:
            result = {**made, "return_mean": 2 * value, "physical": {"bounces_per_10s": value}}
            (run / file).write_text(json.dumps(result))
    return run


def read_rows(path):
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def test_compare_pairs_runs_by_seed(tmp_path, capsys):
    base, test, out = tmp_path / "f32", tmp_path / "bf16", tmp_path / "out"
    write_run(base, "s0", 0, "float32", [10, 20], 1000, best=20, latest=20)  # only in the base set
    write_run(base, "s1", 1, "float32", [30, 40], 1000, best=40, latest=30)
    write_run(base, "s2", 2, "float32", [30, 20], 1200, best=30, latest=20)  # falls back: 20 / 30
    write_run(test, "s1", 1, "bfloat16", [40, 44], 1500, best=44, latest=44)
    write_run(test, "s2", 2, "bfloat16", [40, 30], 1500, best=36, latest=35)
    write_run(test, "s5", 5, "bfloat16", [1, 2], 1500, best=2, latest=2)  # only in the test set
    analyse.main(["compare", str(test / "*"), "--against", str(base / "*"), "--out", str(out)])
    printed = capsys.readouterr().out
    rows = read_rows(out / "compare.csv")
    # the final checkpoints' re-evaluations: differences 44 - 30 = 14 and 35 - 20 = 15
    assert [[float(r[k]) for k in ("seed", "base_final", "test_final", "difference")] for r in rows] == [
        [1, 30, 44, 14],
        [2, 20, 35, 15],
    ]
    assert [float(r["base_held"]) for r in rows] == pytest.approx([0.75, 2 / 3])
    assert "base (--against) -> test: agent.precision: 'float32' -> 'bfloat16'" in printed
    assert "final checkpoints re-evaluated on 1000 episodes" in printed
    # mean 14.5, differences' std 0.707 / sqrt(2) = 0.5: +29 standard errors; best 35 -> 40;
    # holding 0 -> 2 of 2; median frames/s 1100 -> 1500
    assert "2 seeds: final 25 -> 39.5, paired difference +14.5 +- 0.5 (+29.00 standard errors)" in printed
    assert "best 35 -> 40; holding 0 -> 2 of 2; frames/s x1.36" in printed
    assert "| 2 | 20 | 35 | +15 | 0.67 (fell back) | 0.97 | 1,200 | 1,500 |" in printed
    assert "left out (in one set only): seeds 0, 5" in printed
    # another metric of the same evaluations: the return, twice the bounces in these runs
    both = ["compare", str(test / "*"), "--against", str(base / "*"), "--out", str(out)]
    analyse.main([*both, "--metric", "return_mean"])
    printed = capsys.readouterr().out
    assert "2 seeds: final 50 -> 79, paired difference +29 +- 1 (+29.00 standard errors)" in printed
    no_column = r"--metric bounce: .*eval\.csv has no such column; give one of return_mean, bounces_per_10s$"
    with pytest.raises(SystemExit, match=no_column):
        analyse.main([*both, "--metric", "bounce"])
    # one run without its final checkpoint re-evaluated: every pair falls back to the in-run values
    (test / "s2" / "eval-latest.json").unlink()
    analyse.main(both)
    assert "final evaluations during training" in capsys.readouterr().out
    rows = read_rows(out / "compare.csv")
    assert [float(rows[1][k]) for k in ("base_final", "test_final", "test_held")] == [20, 30, 0.75]
    analyse.main(["compare", str(test / "s1"), "--against", str(base / "s1"), "--out", str(out)])
    printed = capsys.readouterr().out
    assert "1 seed: final 30 -> 44, paired difference +14 (one pair: no standard error)" in printed


def test_compare_rejects_sets_it_cannot_pair(tmp_path):
    base, test = tmp_path / "f32", tmp_path / "bf16"
    write_run(base, "s0", 0, "float32", [1, 2], 1000)
    write_run(test, "s1", 1, "bfloat16", [1, 2], 1000)
    args = ["compare", str(test / "*"), "--out", str(tmp_path / "out"), "--against", str(base / "*")]
    with pytest.raises(
        SystemExit, match=r"^analyse compare: no seed is in both sets \(runs: \[1\], --against: \[0\]\)"
    ):
        analyse.main(args)
    write_run(test, "s0", 0, "bfloat16", [1, 2], 1000)
    write_run(test, "s0-again", 0, "bfloat16", [1, 2], 1000)
    with pytest.raises(
        SystemExit, match=r"s0 and .*s0-again are both seed 0 of bounce_ppo: keep one of them"
    ):
        analyse.main(args)
    (test / "s0-again" / "summary.json").unlink()  # unfinished: left out with a line, no longer a duplicate
    with pytest.raises(SystemExit, match=r"compare compares runs of one task"):
        (test / "s1" / "config.yaml").write_text(
            "exp_name: find_ppo\nseed: 1\ntotal_frames: 200\nenv:\n  task: find\n"
        )
        analyse.main(args)
    with pytest.raises(SystemExit):  # argparse: --against is required
        analyse.main(["compare", str(test / "*")])
