"""Faults and bad input: values refused in one line naming the key before any work, runs that
stop or break leave something usable and say what to do, analysis tools refuse what they cannot
count."""

import math
import pickle
import shlex
import signal
from pathlib import Path

import gymnasium
import pytest
from helpers import TINY, compose_cfg

import roto_trl  # noqa: F401  registers the Gymnasium ids
from roto_trl import make_env
from roto_trl.train import train
from roto_trl.trainers.errors import TrainingInterrupted

# ---------------------------------------------------------------------------- env values


@pytest.mark.parametrize("scale", [math.nan, math.inf, -math.inf])
def test_a_reward_scale_that_is_not_finite_is_refused_by_every_door(scale, tmp_path):
    message = r"^reward_scales\['air'\] must be a finite number, got (nan|inf|-inf)$"
    with pytest.raises(ValueError, match=message):
        make_env("bounce", 2, reward_scales={"air": scale})
    with pytest.raises(ValueError, match=message):
        gymnasium.make_vec("RoTO/Bounce-v0", num_envs=2, reward_scales={"air": scale})
    run = tmp_path / "run"
    with pytest.raises(ValueError, match=message):  # before the run directory exists
        train(
            compose_cfg(
                ["+exp=bounce_ppo", *TINY, f"+env.overrides.reward_scales.air={scale}", f"run_dir={run}"]
            )
        )
    assert not run.exists()


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ({"substeps": 2.5}, "substeps must be an integer, got 2.5"),
        ({"history": 1.5}, "history must be an integer, got 1.5"),
        ({"history": True}, "history must be an integer, got True"),
        ({"episode_steps": 0}, "episode_steps must be >= 1, got 0"),
        ({"num_threads": 0}, r"num_threads must be >= 1 or None \(every core\), got 0"),
        ({"action_ema": math.nan}, "action_ema must be a finite number, got nan"),
        ({"contact_threshold": -1.0}, "contact_threshold must be >= 0 N, got -1.0"),
        ({"seed": -1}, "seed must be an integer >= 0, got -1"),
        ({"seed": "a"}, "seed must be an integer >= 0, got 'a'"),
    ],
)
def test_make_env_refuses_a_value_of_the_wrong_type_naming_the_key(override, message):
    with pytest.raises(ValueError, match=f"^{message}$"):
        make_env("find", 2, **override)


def test_gymnasium_reset_checks_its_seed_and_options():
    envs = gymnasium.make_vec("RoTO/Find-v0", num_envs=2)
    single = gymnasium.make("RoTO/Find-v0")
    for env in (envs, single):
        for seed in (1.5, -1, "a", True):
            with pytest.raises(
                ValueError, match=r"^reset\(seed=\.\.\.\) must be None or an integer >= 0, got"
            ):
                env.reset(seed=seed)
        with pytest.raises(ValueError, match=r"^reset\(options=\.\.\.\) must be None or a dict, got 'x'$"):
            env.reset(options="x")
        env.reset(seed=3, options={})
        env.close()


# ---------------------------------------------------------------------------- analysis of run directories


def hand_run(root, name, seed, evals, budget=200, finished=True, exp="find_ppo"):
    """A Find run written by hand: ``evals`` its reached_3cm at frames 100, 200, ..."""
    run = root / name
    run.mkdir(parents=True)
    (run / "config.yaml").write_text(
        f"exp_name: {exp}\nseed: {seed}\ntotal_frames: {budget}\nenv:\n  task: find\n"
    )
    rows = "".join(f"{100 * (i + 1)},{v},{v}\n" for i, v in enumerate(evals))
    (run / "eval.csv").write_text("frames,return_mean,reached_3cm\n" + rows)
    (run / "train.csv").write_text(f"frames,fps\n{100 * len(evals)},10\n")
    if finished:
        (run / "summary.json").write_text("{}")
    return run


def table_rows(out):
    import csv

    with (out / "table.csv").open(newline="") as handle:
        return {(r["exp_name"], r["metric"]): r for r in csv.DictReader(handle) if r["at"] == "final"}


def test_the_table_leaves_out_failed_and_early_runs_and_says_which(tmp_path, capsys):
    from roto_trl import analyse

    hand_run(tmp_path / "runs", "a", 0, [0.2, 0.4])
    hand_run(tmp_path / "runs", "b", 1, [0.4, 0.6])
    hand_run(tmp_path / "runs", "stopped", 2, [], finished=False)  # a multirun job stopped at frame 0
    (tmp_path / "runs" / "stopped" / "eval.csv").write_text(
        "frames,return_mean,reached_3cm\n"
    )  # the header only
    failed = hand_run(tmp_path / "runs", "failed", 3, [0.1], finished=False)
    (failed / "error.txt").write_text("Traceback ...\nNonFiniteError: the return estimate is NaN or inf\n")
    hand_run(tmp_path / "runs", "early", 4, [0.9], finished=False)
    analyse.main(["table", str(tmp_path / "runs" / "*"), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert f"left out {tmp_path / 'runs' / 'stopped'}: it holds no evaluation" in err
    assert f"left out {failed}: it failed (NonFiniteError: the return estimate is NaN or inf)" in err
    assert f"left out {tmp_path / 'runs' / 'early'}: it ended early, at 100 of 200 frames" in err
    row = table_rows(tmp_path / "out")[("find_ppo", "reached_3cm")]
    assert (row["seeds"], float(row["mean"])) == ("2", pytest.approx(0.5))  # a and b only
    for command in ("curves", "stability"):  # the header-only eval.csv is a line there too, not a KeyError
        more = ["--no-physical"] if command == "curves" else []
        analyse.main([command, str(tmp_path / "runs" / "*"), "--out", str(tmp_path / command), *more])
        assert "it holds no evaluation" in capsys.readouterr().err


def test_a_repeated_seed_is_refused_and_budgets_are_not_mixed(tmp_path, capsys):
    from roto_trl import analyse

    hand_run(tmp_path / "runs", "short", 0, [0.1], budget=100)
    hand_run(tmp_path / "runs", "long", 0, [0.2, 0.3, 0.4], budget=300)
    analyse.main(["table", str(tmp_path / "runs" / "*"), "--out", str(tmp_path / "out")])
    rows = table_rows(tmp_path / "out")
    assert rows[("find_ppo [100 frames]", "reached_3cm")]["seeds"] == "1"  # two groups, one seed each
    assert rows[("find_ppo [300 frames]", "reached_3cm")]["seeds"] == "1"
    hand_run(tmp_path / "runs", "long-again", 0, [0.5, 0.5, 0.5], budget=300)
    with pytest.raises(SystemExit, match=r"long and .*long-again are both seed 0 of find_ppo \[300 frames\]"):
        analyse.main(["table", str(tmp_path / "runs" / "*"), "--out", str(tmp_path / "out")])


def test_a_cut_last_line_is_left_out_and_said(tmp_path, capsys):
    from roto_trl import analyse
    from roto_trl.trainers.loggers import read_csv

    run = hand_run(tmp_path / "runs", "a", 0, [0.2, 0.4])
    with (run / "eval.csv").open("a") as handle:
        handle.write("300,0.9")  # killed while writing the row: no line end, columns missing
    assert read_csv(run / "eval.csv")["frames"] == [100.0, 200.0]
    analyse.main(["table", str(run), "--out", str(tmp_path / "out")])
    assert (
        "its last line of eval.csv is cut (a kill while writing it) and is left out"
        in capsys.readouterr().err
    )
    row = table_rows(tmp_path / "out")[("find_ppo", "reached_3cm")]
    assert float(row["mean"]) == pytest.approx(0.4) and int(row["frames"]) == 200
    analyse.main(["stability", str(run), "--out", str(tmp_path / "stability")])
    assert (
        "| reached_3cm | 200 | 0.4 (200) | 0.4 | 1.00 |"
        in (tmp_path / "stability" / "stability.md").read_text()
    )


# ---------------------------------------------------------------------------- runs that stop or break


@pytest.fixture
def finished_run(tmp_path):
    """A finished smoke run of find_ppo (2 iterations of 8 worlds x 16 steps, best and latest)."""
    run = tmp_path / "run"
    train(compose_cfg(["+exp=find_ppo", *TINY, f"run_dir={run}"]))
    return run


def resume(run, frames=384):
    return train(compose_cfg([f"resume={run}", f"total_frames={frames}"]), [f"total_frames={frames}"])


def test_a_config_of_another_task_than_the_checkpoint_is_one_line(finished_run):
    text = (finished_run / "config.yaml").read_text().replace("task: find", "task: bounce")
    (finished_run / "config.yaml").write_text(text)
    with pytest.raises(
        ValueError,
        match=r"config\.yaml has env\.task=bounce but .*latest\.pt was trained with env\.task=find",
    ):
        resume(finished_run)


def test_an_unreadable_config_falls_back_to_the_checkpoints_own(finished_run, capsys):
    from roto_trl.analysis.checkpoint_eval import evaluate_run

    (finished_run / "config.yaml").write_text("env: [unclosed\n")
    evaluate_run(finished_run, "latest", episodes=2)
    assert "cannot be read as YAML" in capsys.readouterr().err
    resume(finished_run)
    assert "continuing with the config latest.pt holds" in capsys.readouterr().out
    assert "task: find" in (finished_run / "config.yaml").read_text()  # written back


def test_resume_needs_only_latest_pt_and_can_take_another_checkpoint(finished_run, capsys):
    from roto_trl.trainers.checkpoint import load_checkpoint

    best = finished_run / "checkpoints" / "best.pt"
    best.write_bytes(b"damaged")
    resume(finished_run)
    assert "best.pt cannot be read; it is replaced by the next best evaluation" in capsys.readouterr().out
    assert load_checkpoint(finished_run)["frames"] == 384
    (finished_run / "checkpoints" / "latest.pt").write_bytes(b"damaged")
    with pytest.raises(ValueError, match=r"latest\.pt cannot be read"):
        resume(finished_run, 512)
    resume(best, 512)  # the best checkpoint of the resumed part: on from there
    assert load_checkpoint(finished_run)["frames"] == 512


def test_a_finished_run_missing_its_end_files_gets_them_back_on_resume(finished_run, capsys):
    for name in ("eval.json", "index.md", "plots/eval.png"):
        (finished_run / name).unlink()
    train(compose_cfg([f"resume={finished_run}"]), [f"resume={finished_run}"])
    assert "wrote the end files it lacked (plots/eval.png, eval.json, index.md)" in capsys.readouterr().out
    assert all((finished_run / name).is_file() for name in ("eval.json", "index.md", "plots/eval.png"))


def test_a_run_stopped_before_its_first_checkpoint_says_how_to_start_it_again(tmp_path):
    from roto_trl.trainers.errors import NonFiniteError

    run = tmp_path / "run"
    overrides = ["+exp=find_ppo", *TINY, f"run_dir={run}", "+env.overrides.reward_scales.dist=1e308"]
    with pytest.raises(NonFiniteError) as stop:  # the first rollout's returns are inf
        train(compose_cfg(overrides), overrides)
    assert stop.value.saved_frames is None
    assert stop.value.what_now.startswith("No checkpoint was written before it")
    with pytest.raises(FileNotFoundError, match=r"stopped before its first checkpoint") as missing:
        train(compose_cfg([f"resume={run}"]), [f"resume={run}"])
    # the run's own overrides, not the process's command line (a multirun worker's is the launcher's)
    command = shlex.join(["python", "roto_trl/train.py", *overrides])
    assert str(missing.value).endswith(f"start it again with its command: {command}")


@pytest.mark.parametrize("override", ["agent.lr=10", "ssl.coeff=1e9"])
def test_a_diverging_run_warns_then_stops(override, tmp_path, capsys):
    from roto_trl.trainers.errors import DivergedError

    run = tmp_path / "run"
    steps = ["total_frames=2048", "divergence.stop_after=3", "checkpoint.interval_minutes=0"]
    with pytest.raises(DivergedError, match="diverged for 3 iterations in a row"):
        train(compose_cfg(["+exp=bounce_fd", *TINY, "ssl.seq_len=4", override, *steps, f"run_dir={run}"]))
    assert "warning: the run diverges at 128 frames" in capsys.readouterr().err


def test_the_logs_grow_by_a_row_per_iteration_and_resume_cuts_them_line_by_line(tmp_path):
    from roto_trl.trainers.loggers import truncate_csv

    run = tmp_path / "run"
    train(compose_cfg(["+exp=bounce_fd", *TINY, "ssl.seq_len=4", f"run_dir={run}"]))
    assert not (run / "aux.csv").exists()  # every auxiliary step only with logger.aux_minibatches=true
    path = tmp_path / "big.csv"
    with path.open("w") as handle:
        handle.write("frames,x\n" + "".join(f"{i},{i}\n" for i in range(1, 200_001)) + "200001,9")
    assert truncate_csv(path, 100_000) == 100_001  # 100,000 whole rows past the cut and the cut one
    assert path.read_text().splitlines()[-1] == "100000,100000"


def test_a_process_told_to_stop_with_its_parent_gets_sigterm_when_the_parent_dies(tmp_path):
    """The watchdog of a multirun worker: the parent exits at once, the child is SIGTERMed and
    knows itself orphaned (it was not while the parent lived)."""
    import subprocess
    import sys
    import time

    marker, ready = tmp_path / "stopped", tmp_path / "ready"
    child = (
        "import signal, sys, time, pathlib\n"
        "from roto_trl.trainers.interrupts import orphaned, stop_with_parent\n"
        f"stop = lambda *_: (pathlib.Path({str(marker)!r}).write_text(str(orphaned())), sys.exit(0))\n"
        "signal.signal(signal.SIGTERM, stop)\n"
        "stop_with_parent(0.05)\n"
        f"pathlib.Path({str(ready)!r}).write_text(str(orphaned()))\n"
        "time.sleep(30)\n"
    )
    parent = (
        "import pathlib, subprocess, sys, time\n"
        f"subprocess.Popen([sys.executable, '-c', {child!r}])\n"
        f"while not pathlib.Path({str(ready)!r}).exists(): time.sleep(0.05)\n"  # then exit, alive child
    )
    subprocess.run([sys.executable, "-c", parent], check=True, timeout=30)  # exits, leaving the child
    deadline = time.time() + 20
    while time.time() < deadline and not marker.exists():
        time.sleep(0.1)
    assert marker.exists() and marker.read_text() == "True"
    assert ready.read_text() == "False"


def test_evaluating_another_checkpoint_or_policy_leaves_eval_json_alone(finished_run):
    from roto_trl.analysis.checkpoint_eval import evaluate_run

    before = (finished_run / "eval.json").read_text()
    assert evaluate_run(finished_run, "latest", episodes=2).name == "eval-latest.json"
    assert (
        evaluate_run(finished_run, "best", episodes=2, policy="stochastic").name
        == "eval-best-stochastic.json"
    )
    assert (finished_run / "eval.json").read_text() == before


def test_evaluate_and_record_print_their_keys_with_help(capsys):
    from roto_trl.evaluate import main as evaluate_main
    from roto_trl.record import main as record_main

    for main, keys in (
        (evaluate_main, ("run ", "checkpoint ", "policy ", "out ")),
        (record_main, ("task ", "policy ")),
    ):
        with pytest.raises(SystemExit) as stop:
            main(["--help"])
        printed = capsys.readouterr().out
        assert stop.value.code == 0 and all(key in printed for key in keys)


def test_a_stopped_job_s_error_crosses_to_the_multirun_launcher_intact():
    """A joblib job's error reaches the launcher pickled; a stopped run's must unpickle with its
    fields (a plain KeyboardInterrupt subclass with its own arguments did not)."""
    err = TrainingInterrupted(1_234_567, signal.SIGTERM, Path("runs/x"))
    back = pickle.loads(pickle.dumps(err))
    assert isinstance(back, TrainingInterrupted) and isinstance(back, KeyboardInterrupt)
    assert (back.frames, back.signum, back.run_dir) == (1_234_567, signal.SIGTERM, Path("runs/x"))
    assert str(back) == "stopped at 1,234,567 frames"
