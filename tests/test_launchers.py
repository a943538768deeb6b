"""Many runs at once: multiruns through Hydra's joblib and submitit launchers, each job with its
own run directory and its share of the cores, and a job requeued by submitit resuming its run."""

import contextlib
import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml
from helpers import TINY, TRAIN, compose_cfg
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from roto_trl.train import place_multirun_job
from roto_trl.trainers.threads import job_threads
from roto_trl.utils.resources import resource_dir

JOBLIB = {"_target_": "hydra_plugins.hydra_joblib_launcher.joblib_launcher.JoblibLauncher"}
SLURM = {"_target_": "hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher"}
BASIC = {"_target_": "hydra._internal.core_plugins.basic_launcher.BasicLauncher"}
# TINY without its fixed torch_threads, so that the job's share shows
TINY_SHARED = [o for o in TINY if not o.startswith("torch_threads")]


@pytest.mark.parametrize(
    ("launcher", "cores", "expected"),
    [
        ({**JOBLIB, "n_jobs": 2}, 2, 1),
        ({**JOBLIB, "n_jobs": 4}, 32, 8),
        ({**JOBLIB, "n_jobs": 3}, 8, 2),  # 8 // 3: two cores stay free rather than oversubscribe
        ({**JOBLIB, "n_jobs": 8}, 2, 1),  # never below one thread
        ({**JOBLIB, "n_jobs": -1}, 16, 1),  # joblib's -1: one job per core
        ({**JOBLIB, "n_jobs": -3}, 16, 1),  # 14 jobs on 16 cores
        ({**JOBLIB, "n_jobs": -13}, 16, 4),  # 4 jobs on 16 cores
        ({**SLURM, "cpus_per_task": 8}, 64, 8),
        ({**SLURM, "cpus_per_task": 8}, 4, 4),  # never more than the cores there are
        ({**SLURM, "cpus_per_task": None}, 64, None),  # the defaults: the cores SLURM gave
        (BASIC, 16, None),  # one job after another: each has every core
    ],
)
def test_job_threads(launcher, cores, expected):
    assert job_threads(launcher, cores) == expected


def test_slurm_launcher_config_composes():
    with initialize_config_dir(str(resource_dir("conf")), version_base="1.3"):
        cfg = compose("train", ["exp=bounce_ppo", "hydra/launcher=slurm"], return_hydra_config=True)
    launcher = cfg.hydra.launcher
    assert launcher._target_ == SLURM["_target_"]
    assert (launcher.cpus_per_task, launcher.timeout_min, launcher.max_num_timeout) == (8, 1440, 20)
    assert job_threads(launcher, 64) == 8


def test_a_multirun_job_runs_in_its_job_directory_and_continues_a_checkpoint_there(tmp_path):
    basic = "hydra._internal.core_plugins.basic_sweeper.BasicSweeper"
    hydra_cfg = OmegaConf.create(
        {
            "launcher": {**JOBLIB, "n_jobs": 64},
            "runtime": {"output_dir": str(tmp_path)},
            "sweeper": {"_target_": basic},
            "job": {"num": 3},
        }
    )
    cfg = compose_cfg(["+exp=find_ppo"])
    assert not place_multirun_job(cfg, hydra_cfg)
    assert (cfg.run_dir, cfg.resume) == (str(tmp_path), None)  # a first start: a new run there
    assert cfg.torch_threads == 1 and cfg.env.overrides.num_threads == 1  # one thread each
    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "checkpoints" / "latest.pt").write_bytes(b"")
    cfg = compose_cfg(["+exp=find_ppo", "torch_threads=3", "+env.overrides.num_threads=2"])
    assert place_multirun_job(cfg, hydra_cfg)
    assert (cfg.run_dir, cfg.resume) == (None, str(tmp_path))  # requeued: continue the run
    assert cfg.torch_threads == 3 and cfg.env.overrides.num_threads == 2  # given values win
    cfg = compose_cfg(["+exp=find_ppo", f"run_dir={tmp_path / 'mine'}"])
    assert not place_multirun_job(cfg, hydra_cfg)
    assert (cfg.run_dir, cfg.resume) == (str(tmp_path / "mine" / "3"), None)  # one run_dir: a job each
    hydra_cfg.sweeper._target_ = "hydra_plugins.roto_optuna_sweeper.sweeper.OptunaSweeper"
    cfg = compose_cfg(["+exp=find_ppo", f"run_dir={tmp_path / 'trial'}"])
    assert not place_multirun_job(cfg, hydra_cfg)
    assert cfg.run_dir == str(tmp_path / "trial")  # our sweeper's trial directory stays as it is


# Each job trains for several seconds: a job of TINY's 256 frames ended in 1.8 s on CI, before the
# second worker, still importing torch, had started its own (2 s later), so "at once" was not seen.
MULTIRUN_FRAMES = 4096


def multirun(sweep_dir: Path, *args: str, timeout: float = 400) -> subprocess.CompletedProcess:
    frames = [f"total_frames={MULTIRUN_FRAMES}", f"eval.every_frames={MULTIRUN_FRAMES}"]
    command = [*TRAIN, "-m", *TINY_SHARED, *frames, "seed=0,1", f"hydra.sweep.dir={sweep_dir}", *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=timeout)


def check_both_runs(sweep_dir: Path, threads: int) -> None:
    """Both jobs finished in their own run directories with ``threads`` torch and physics threads."""
    for seed in (0, 1):
        run_dir = sweep_dir / f"{seed}-find_ppo-s{seed}"  # <job number>-<exp_name>-s<seed>
        summary = json.loads((run_dir / "summary.json").read_text())
        assert (summary["seed"], summary["frames"]) == (seed, MULTIRUN_FRAMES)
        assert (run_dir / "eval.json").is_file()
        config = yaml.safe_load((run_dir / "config.yaml").read_text())
        assert config["run_dir"] == str(run_dir)
        assert config["torch_threads"] == threads and config["env"]["overrides"]["num_threads"] == threads


def assert_ran_at_once(sweep_dir: Path) -> None:
    """The two runs overlapped in time: each started (config.yaml) before the other ended (summary.json)."""
    start = [(sweep_dir / f"{s}-find_ppo-s{s}" / "config.yaml").stat().st_mtime for s in (0, 1)]
    end = [(sweep_dir / f"{s}-find_ppo-s{s}" / "summary.json").stat().st_mtime for s in (0, 1)]
    assert start[0] < end[1] and start[1] < end[0], "the jobs ran one after another"


@pytest.mark.slow  # end to end: Hydra's launcher or sweeper starts training processes
def test_two_jobs_at_once_through_joblib(tmp_path):
    done = multirun(tmp_path, "hydra/launcher=joblib", "hydra.launcher.n_jobs=2")
    assert done.returncode == 0, done.stderr[-3000:]
    check_both_runs(tmp_path, max(1, len(os.sched_getaffinity(0)) // 2))
    assert_ran_at_once(tmp_path)


@pytest.mark.slow  # end to end: Hydra's launcher or sweeper starts training processes
def test_two_jobs_through_submitit_local(tmp_path):
    done = multirun(tmp_path, "hydra/launcher=submitit_local", "hydra.launcher.cpus_per_task=1")
    assert done.returncode == 0, done.stderr[-3000:]
    check_both_runs(tmp_path, 1)
    assert_ran_at_once(tmp_path)
    assert list(tmp_path.glob(".submitit/*/*_result.pkl")), "submitit wrote no job results"


def _submitit_task_pid(sweep_dir: Path) -> int | None:
    """The process of the submitit job running under ``sweep_dir`` (the task, not its controller)."""
    for proc in Path("/proc").iterdir():
        try:
            command = (proc / "cmdline").read_bytes().split(b"\0")
        except (OSError, ValueError):
            continue
        if b"submitit.core._submit" in command and any(str(sweep_dir).encode() in a for a in command):
            return int(proc.name)
    return None


@pytest.mark.slow
def test_job_interrupted_by_its_time_limit_is_requeued_and_resumes(tmp_path):
    """submitit_local is the local equivalent of SLURM: SIGUSR2 is what a job gets before its time
    limit (or on preemption); submitit requeues it, and the new start continues the run."""
    command = [
        *TRAIN,
        "-m",
        *TINY,
        "total_frames=2560",  # 20 iterations, a checkpoint after each
        f"hydra.sweep.dir={tmp_path}",
        "hydra/launcher=submitit_local",
    ]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    run_dir = tmp_path / "0-find_ppo-s0"
    latest = run_dir / "checkpoints" / "latest.pt"
    deadline = time.time() + 300
    while time.time() < deadline and not latest.exists() and proc.poll() is None:
        time.sleep(0.1)
    assert latest.exists(), "the job wrote no checkpoint"
    pid = _submitit_task_pid(tmp_path)
    assert pid is not None, "no submitit job process found"
    os.kill(pid, signal.SIGUSR2)
    output, _ = proc.communicate(timeout=400)
    assert proc.returncode == 0, output[-3000:]
    logs = "".join(p.read_text() for p in tmp_path.glob(".submitit/*/*_log.*"))
    assert "Requeued job" in logs
    assert f"resuming {run_dir}" in logs
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["frames"] == 2560 and summary["iterations"] == 20


def _state_and_parent(pid: int | str) -> tuple[str, int] | None:
    """A process's state letter and parent pid from ``/proc/<pid>/stat``; None once it is gone."""
    try:
        state, ppid = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[:2]
    except OSError:
        return None
    return state, int(ppid)


def _children(pid: int) -> list[int]:
    """The processes whose parent is ``pid``."""
    procs = Path("/proc").glob("[0-9]*")
    return [int(p.name) for p in procs if (_state_and_parent(p.name) or ("", 0))[1] == pid]


def _alive(pid: int) -> bool:
    """Running, not a zombie waiting to be reaped."""
    return (_state_and_parent(pid) or ("Z", 0))[0] != "Z"


@pytest.mark.slow
def test_a_killed_joblib_sweep_stops_its_job_and_leaves_no_worker_behind(tmp_path):
    """SIGTERM to the sweep's own process: its worker's job finishes the iteration, writes its
    checkpoint, releases the run, prints where it stopped, and the worker process ends."""
    log = (tmp_path / "sweep.log").open("w")
    command = [*TRAIN, "-m", *TINY, "total_frames=1000000", "seed=0", "hydra/launcher=joblib"]
    proc = subprocess.Popen([*command, f"hydra.sweep.dir={tmp_path}"], stdout=log, stderr=log)
    run_dir = tmp_path / "0-find_ppo-s0"
    deadline = time.time() + 300
    while time.time() < deadline and not (run_dir / "checkpoints" / "latest.pt").exists():
        assert proc.poll() is None, (tmp_path / "sweep.log").read_text()[-3000:]
        time.sleep(0.1)
    worker = json.loads((run_dir / ".lock.owner").read_text())["pid"]  # the job's process
    assert worker != proc.pid and _alive(worker)
    others = [pid for pid in _children(proc.pid) if pid != worker]  # loky's trackers, an idle worker
    proc.terminate()
    proc.wait(timeout=60)
    deadline = time.time() + 120
    while time.time() < deadline and _alive(worker):
        time.sleep(0.2)
    output = (tmp_path / "sweep.log").read_text()
    assert not _alive(worker), f"the job's worker stayed behind: {output[-3000:]}"
    assert "train: stopped at" in output and f"resume={run_dir}" in output, output[-3000:]
    assert not (run_dir / ".lock.owner").exists()
    for pid in others:  # a worker that never had a job ends on loky's idle timeout (5 min): not waited for
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
