"""Run integrity: complete CSV logs, one writer per run directory, logs that match the checkpoint
after a resume, what resume may change, clean interrupts, full disks and unwritable paths."""

import csv
import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers import TINY, TRAIN, compose_cfg

from roto_trl.train import train
from roto_trl.trainers.checkpoint import load_checkpoint, save_checkpoint
from roto_trl.trainers.errors import RunInUse, WriteError
from roto_trl.trainers.evaluation import selection_key
from roto_trl.trainers.loggers import MetricLogger, read_csv, truncate_csv
from roto_trl.trainers.run_dir import RESUMABLE, reconcile_best
from roto_trl.trainers.run_lock import RunLock

ROOT = Path(__file__).resolve().parent.parent
FRAMES_PER_ITERATION = 8 * 16  # TINY: 8 worlds x 16 steps


def frames_of(path: Path) -> list[int]:
    with path.open(newline="") as handle:
        return [int(float(row["frames"])) for row in csv.DictReader(handle)]


def tiny(run: Path, *extra: str) -> list[str]:
    return ["+exp=bounce_ppo", *TINY, f"run_dir={run}", *extra]


# ---------------------------------------------------------------------------- 0. complete CSV logs


def test_a_metric_first_logged_in_a_later_row_gets_its_column(tmp_path):
    logger = MetricLogger(tmp_path, "csv")
    logger.log("train", {"reward": 1.0}, 128)
    logger.log("train", {"reward": 2.0, "episode_return": 5.0}, 256)
    logger.log("train", {"reward": 3.0, "episode/bounces": 1.0}, 384)
    logger.close()
    table = read_csv(tmp_path / "train.csv")
    assert list(table) == ["frames", "reward", "episode_return", "episode/bounces"]
    assert table["reward"] == [1.0, 2.0, 3.0]
    assert math.isnan(table["episode_return"][0]) and table["episode_return"][1] == 5.0
    assert math.isnan(table["episode/bounces"][1]) and table["episode/bounces"][2] == 1.0


def test_a_trained_run_logs_episode_returns_and_evaluation_time(tmp_path):
    # the first iteration ends no episode (16 of 40 steps): its return appears later
    train(compose_cfg(tiny(tmp_path / "run", "total_frames=768")))
    train_log, eval_log = read_csv(tmp_path / "run" / "train.csv"), read_csv(tmp_path / "run" / "eval.csv")
    returns = train_log["episode_return"]
    assert math.isnan(returns[0]) and any(math.isfinite(r) for r in returns)
    assert "episode/bounces" in train_log and "episodes" in train_log
    assert all(t > 0 for t in eval_log["time"])  # every evaluation is timed, the start's too


# ---------------------------------------------------------------------------- 1. one writer


def test_a_second_writer_is_refused_naming_the_holder_before_touching_anything(tmp_path):
    fresh, finished = tmp_path / "fresh", tmp_path / "finished"
    fresh.mkdir()
    train(compose_cfg(tiny(finished)))
    with RunLock(fresh):
        with pytest.raises(RunInUse, match=rf"in use by pid {os.getpid()} on {socket.gethostname()}"):
            train(compose_cfg(tiny(fresh)))
        assert sorted(p.name for p in fresh.iterdir()) == [".lock", ".lock.owner"]  # no config.yaml
    with RunLock(finished):
        held = subprocess.run(
            [*TRAIN, f"resume={finished}", "total_frames=512"], capture_output=True, text=True, timeout=120
        )
    assert held.returncode == 2
    assert f"in use by pid {os.getpid()}" in held.stderr and "Traceback" not in held.stderr
    assert load_checkpoint(finished)["frames"] == 256


def test_the_lock_of_a_killed_process_blocks_nobody(tmp_path):
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from roto_trl.trainers.run_lock import RunLock; "
            f"lock = RunLock({str(tmp_path)!r}).acquire(); print('held', flush=True); time.sleep(60)",
        ],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert holder.stdout.readline().strip() == "held"
    with pytest.raises(RunInUse, match=f"pid {holder.pid}"):
        RunLock(tmp_path).acquire()
    holder.kill()
    holder.wait()
    RunLock(tmp_path).acquire().release()


# ---------------------------------------------------------------------------- 2. resume = one run


def test_resume_cuts_the_logs_back_to_the_checkpoint(tmp_path):
    run = tmp_path / "run"
    train(compose_cfg(tiny(run)))  # 256 frames
    at_256 = tmp_path / "latest-256.pt"
    shutil.copy(run / "checkpoints" / "latest.pt", at_256)
    train(compose_cfg([f"resume={run}", "total_frames=384"]), ["total_frames=384"])
    # a kill after the 384-frame rows (evaluation included) but before their checkpoint, half a
    # row written: latest.pt is back at 256
    shutil.copy(at_256, run / "checkpoints" / "latest.pt")
    with (run / "train.csv").open("a") as handle:
        handle.write("58.31207803799998")
    assert frames_of(run / "eval.csv") == [0, 256, 384]
    train(compose_cfg([f"resume={run}", "total_frames=512"]), ["total_frames=512"])
    assert frames_of(run / "train.csv") == [128, 256, 384, 512]
    assert frames_of(run / "eval.csv") == [0, 256, 512]
    latest, best = load_checkpoint(run), load_checkpoint(run / "checkpoints" / "best.pt")
    assert best["frames"] == latest["best_eval_metrics"]["frames"]
    evals = read_csv(run / "eval.csv")
    best_key = max(zip(evals["bounces_per_10s"], evals["return_mean"], strict=True))
    assert selection_key(latest["best_eval_metrics"], "bounces_per_10s") == best_key


def test_truncate_csv_keeps_rows_up_to_the_checkpoint(tmp_path):
    path = tmp_path / "train.csv"
    path.write_text("frames,x\n128,1\n256,2\n384,3\n2")
    assert truncate_csv(path, 256) == 2
    assert path.read_text() == "frames,x\n128,1\n256,2\n"
    path.write_text("frames,x\n128,1\n256,2\n38")  # a row cut short by a kill
    assert truncate_csv(path, 1000) == 1 and path.read_text() == "frames,x\n128,1\n256,2\n"


def _checkpoint(path: Path, frames: int, best_at: int | None) -> dict:
    state = {"agent": {}, "optimizer": {}, "config": {}, "frames": frames, "iteration": 1}
    state |= {"wall_time": 1.0, "eval_time": 0.5}
    state["best_eval_metrics"] = None if best_at is None else {"frames": best_at, "return_mean": 1.0}
    save_checkpoint(path, state)
    return state


def test_best_pt_is_made_to_agree_with_the_checkpoint(tmp_path):
    latest_path, best_path = tmp_path / "latest.pt", tmp_path / "best.pt"
    # a kill between latest.pt (a new best at 512) and best.pt: best.pt becomes latest.pt
    latest = _checkpoint(latest_path, 512, best_at=512)
    _checkpoint(best_path, 256, best_at=256)
    reconcile_best(tmp_path, latest)
    assert load_checkpoint(best_path)["frames"] == 512 and latest["best_eval_metrics"]["frames"] == 512
    # best.pt from iterations the resume discards: removed, its best forgotten
    latest = _checkpoint(latest_path, 512, best_at=256)
    _checkpoint(best_path, 768, best_at=768)
    reconcile_best(tmp_path, latest)
    assert not best_path.exists()
    assert latest["best_eval_metrics"] is None


# ---------------------------------------------------------------------------- 3. what resume may change


def test_resume_leaves_a_finished_run_alone_and_takes_only_a_larger_budget(tmp_path, capsys):
    run = tmp_path / "run"
    train(compose_cfg(tiny(run)))

    def stamps():
        return {p: p.stat().st_mtime_ns for p in run.rglob("*") if p.is_file() and p.name != ".lock.owner"}

    before = stamps()
    train(compose_cfg([f"resume={run}"]), [f"resume={run}"])
    said = "nothing to train, it is finished at 256 frames (total_frames=256); it is unchanged"
    assert said in capsys.readouterr().out
    extra = ["total_frames=512", "agent.lr=5e-4"]
    with pytest.raises(ValueError, match=f"only {', '.join(RESUMABLE)} may change on resume, not agent.lr"):
        train(compose_cfg([f"resume={run}", *extra]), [f"resume={run}", *extra])
    assert stamps() == before
    summary = json.loads(
        train(compose_cfg([f"resume={run}", "total_frames=384"]), ["total_frames=384"]).read_text()
    )
    assert summary["frames"] == 384 and load_checkpoint(run)["config"]["total_frames"] == 384


# ---------------------------------------------------------------------------- stopping a run safely


@pytest.mark.parametrize(("signum", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_stops_the_run_with_its_checkpoint(tmp_path, signum, status):
    run = tmp_path / "run"
    args = tiny(run, "total_frames=1000000", "checkpoint.interval_minutes=60")
    proc = subprocess.Popen([*TRAIN, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while time.time() < deadline and not (run / "train.csv").is_file():
        time.sleep(0.2)
    while time.time() < deadline and len(frames_of(run / "train.csv")) < 1:
        time.sleep(0.2)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == status, err[-2000:]
    assert "Traceback" not in err
    frames = load_checkpoint(run)["frames"]
    assert f"stopped at {frames:,} frames; continue with: python roto_trl/train.py resume={run}" in err
    assert frames_of(run / "train.csv")[-1] == frames


# ---------------------------------------------------------------------------- full disk, unwritable paths


def test_a_full_disk_at_a_checkpoint_is_one_error_and_keeps_the_logs_consistent(tmp_path):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    tmp = run / "checkpoints" / "latest.pt.tmp"
    tmp.symlink_to("/dev/full")  # every write there fails with ENOSPC, as on a full disk
    with pytest.raises(
        WriteError, match=f"cannot write checkpoint {run}/checkpoints/latest.pt: no space left"
    ):
        train(compose_cfg(tiny(run, "checkpoint.interval_minutes=0")))
    assert not tmp.exists() and not tmp.is_symlink()
    assert frames_of(run / "train.csv") == [] and frames_of(run / "eval.csv") == [0]


def test_a_full_disk_under_a_csv_log_is_one_error(tmp_path):
    (tmp_path / "train.csv").symlink_to("/dev/full")
    logger = MetricLogger(tmp_path, "csv")
    with pytest.raises(WriteError, match=f"cannot write {tmp_path}/train.csv: no space left on device"):
        logger.log("train", {"reward": 1.0}, 128)
    logger.close()  # quietly: the error above was the report


def test_unwritable_run_dirs_are_refused_before_any_work(tmp_path):
    a_file = tmp_path / "file"
    a_file.write_text("")
    with pytest.raises(ValueError, match=f"run_dir={a_file} is a file"):
        train(compose_cfg(tiny(a_file)))
    with pytest.raises(ValueError, match="run_dir=/proc/roto is not writable"):
        train(compose_cfg(tiny(Path("/proc/roto"))))


def test_evaluate_and_record_check_their_arguments_first(tmp_path):
    from roto_trl.evaluate import main as evaluate_main
    from roto_trl.record import main as record_main

    for argv, message in [
        (["run=x", "out=/proc/roto/eval.json"], "out=/proc/roto is not writable"),
        (["run=x", f"out={tmp_path}"], f"out={tmp_path} is a directory"),
        (["run=x", "episodes=1.5"], "episodes must be an integer >= 1 or null, got 1.5"),
        (["run=x", "episodes=abc"], "episodes must be an integer >= 1 or null, got 'abc'"),
    ]:
        with pytest.raises(SystemExit, match=message):
            evaluate_main(argv)
    for argv, message in [
        (["task=find", "width=0"], "width must be an integer >= 2, got 0"),
        (["task=find", f"out={tmp_path}"], f"out={tmp_path} is a directory"),
        (["task=find", "max_steps=0"], "max_steps must be an integer >= 1 or null, got 0"),
    ]:
        with pytest.raises(SystemExit, match=message):
            record_main(argv)


# ---------------------------------------------------------------------------- every key checked first


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("device=tpu", "device must be cpu or cuda"),
        ("torch_threads=-2", "torch_threads must be >= 1, got -2"),
        ("checkpoint.interval_minutes=abc", "checkpoint.interval_minutes must be a number, got abc"),
        ("checkpoint.interval_minutes=-1", "checkpoint.interval_minutes must be >= 0, got -1.0"),
        ("+env.overrides.reward_scales.air=abc", r"reward_scales\['air'\] must be a finite number, got 'ab"),
        ("+env.overrides.substep=2", r"unknown override\(s\) \['substep'\]"),
    ],
)
def test_bad_values_are_refused_before_the_run_directory_exists(tmp_path, override, message):
    with pytest.raises(ValueError, match=message):
        train(compose_cfg(tiny(tmp_path / "run", override)))
    assert not (tmp_path / "run").exists()


# ---------------------------------------------------------------------------- 4. analyse mi


@pytest.mark.parametrize("k", ["0", "-1"])
def test_analyse_mi_needs_k_of_at_least_one(tmp_path, k, capsys):
    from roto_trl.analyse import main as analyse_main
    from roto_trl.analysis.mutual_information import ksg_mutual_information

    with pytest.raises(SystemExit) as stop:
        analyse_main(["mi", str(tmp_path), "--k", k, "--out", str(tmp_path / "out")])
    assert stop.value.code == 2 and f"argument --k: must be >= 1, got {k}" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
    with pytest.raises(ValueError, match="k >= 1"):
        ksg_mutual_information([[0.0]] * 10, [[1.0]] * 10, k=0)


# ---------------------------------------------------------------------------- multirun


@pytest.mark.slow  # end to end: Hydra's launcher or sweeper starts training processes
def test_a_multirun_with_one_run_dir_gives_each_job_its_own(tmp_path):
    run = tmp_path / "runs"
    done = subprocess.run(
        [*TRAIN, "-m", *tiny(run, "total_frames=128", "seed=0,1")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert [load_checkpoint(run / job)["config"]["seed"] for job in ("0", "1")] == [0, 1]


def test_a_run_records_how_it_was_made_at_every_sitting(tmp_path):
    from importlib.metadata import version

    from roto_trl.trainers.provenance import read_provenance

    run = tmp_path / "run"
    train(compose_cfg(tiny(run)), tiny(run))
    train(compose_cfg([f"resume={run}", "total_frames=384"]), [f"resume={run}", "total_frames=384"])
    first, resumed = read_provenance(run)
    assert (first["at_frames"], resumed["at_frames"]) == (0, 256)
    assert (first["overrides"], resumed["overrides"]) == (tiny(run), [f"resume={run}", "total_frames=384"])
    assert len(first["commit"]) == 40 and isinstance(first["dirty"], bool)
    assert first["versions"]["torch"] == version("torch") and first["versions"]["mujoco"] == version("mujoco")
    assert first["precision"] == "float32" and first["torch_threads"] == 1 and first["cpu"]
    assert first["command"] == [Path(sys.orig_argv[0]).name, *sys.orig_argv[1:]]


def test_a_checkout_is_dirty_for_changed_code_not_for_a_log_beside_it(tmp_path):
    from roto_trl.trainers.provenance import git_state

    def git(*args):
        identity = ["-c", "user.name=t", "-c", "user.email=t@t"]
        subprocess.run(["git", "-C", str(tmp_path), *identity, *args], check=True)

    (tmp_path / "roto_trl").mkdir()
    (tmp_path / "roto_trl" / "train.py").write_text("x = 1\n")
    git("init", "-q")
    git("add", ".")
    git("commit", "-q", "-m", "code")
    assert git_state(tmp_path)["dirty"] is False
    (tmp_path / "study.log").write_text("a log\n")  # an untracked output beside the code
    assert git_state(tmp_path)["dirty"] is False
    (tmp_path / "roto_trl" / "extra.py").write_text("y = 2\n")  # untracked code
    assert git_state(tmp_path)["dirty"] is True
    (tmp_path / "roto_trl" / "extra.py").unlink()
    (tmp_path / "roto_trl" / "train.py").write_text("x = 2\n")  # a tracked change
    state = git_state(tmp_path)
    assert state["dirty"] is True and len(state["commit"]) == 40
