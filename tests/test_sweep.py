"""Sweeps: the Optuna sweeper plugin (hydra_plugins/roto_optuna_sweeper), the search spaces of
conf/hparams_search/, and roto_trl.sweep (storage, summary, best trial as an experiment)."""

import json
import math
import os
import pwd
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

import optuna
import pytest
from helpers import TINY, TRAIN
from hydra import compose, initialize_config_dir
from hydra.core.override_parser.overrides_parser import OverridesParser
from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution
from optuna.trial import TrialState

from hydra_plugins.roto_optuna_sweeper._study import render, search_space
from roto_trl.analysis.runs import run_objective
from roto_trl.config import hydra_overrides
from roto_trl.sweep import main as sweep_main
from roto_trl.sweeps.storage import load_study, open_storage, redact
from roto_trl.utils.resources import resource_dir

# A sweep of tiny trials (a few seconds each): PPO's space with R, mb, le and c_ent fixed on the
# command line, so that only agent.lr is searched.
TINY_SWEEP = ["-m", "+exp=find_ppo", "hparams_search=ppo", *TINY, "agent.entropy_coeff=0"]
LOG_LR = FloatDistribution(1e-5, 1e-3, log=True)
PPO_SPACE = {
    "agent.rollout_len": CategoricalDistribution([16, 32, 64]),
    "agent.minibatches": CategoricalDistribution([4, 8, 16, 32, 64]),
    "agent.epochs": CategoricalDistribution([4, 8, 16, 32]),
    "agent.lr": LOG_LR,
    "agent.entropy_coeff": CategoricalDistribution([0, 0.05, 0.1]),
}
SSL_SPACE = {**PPO_SPACE, "ssl.lr": LOG_LR, "ssl.coeff": FloatDistribution(1e-3, 10, log=True)}
DYNAMICS_SPACE = {**SSL_SPACE, "ssl.seq_len": CategoricalDistribution([2, 3, 4, 10])}
MEM_SPACE = {**DYNAMICS_SPACE, "ssl.memory_rollouts": CategoricalDistribution([2, 3, 4])}


def parse(overrides: list[str]):
    return search_space(OverridesParser.create().parse_overrides(overrides))


def sweep(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([*TRAIN, *TINY_SWEEP, *args], capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize(
    ("space", "exp", "expected"),
    [
        ("ppo", "bounce_ppo", PPO_SPACE),
        ("ssl", "bounce_tr", SSL_SPACE),
        ("dynamics", "bounce_fd", DYNAMICS_SPACE),
        ("dynamics_mem", "bounce_fd_mem", MEM_SPACE),
    ],
)
def test_search_spaces_are_table_a3(space, exp, expected):
    with initialize_config_dir(str(resource_dir("conf")), version_base="1.3"):
        overrides = hydra_overrides([f"+exp={exp}", f"hparams_search={space}"])
        cfg = compose("train", overrides=overrides, return_hydra_config=True)
    sweeper = cfg.hydra.sweeper
    assert sweeper._target_ == "hydra_plugins.roto_optuna_sweeper.sweeper.OptunaSweeper"
    assert (sweeper.n_trials, sweeper.n_startup_trials, sweeper.storage) == (20, 5, None)
    assert sweeper.study_name == f"{exp}-{space}" and cfg.hydra.sweep.dir == f"sweeps/{exp}-{space}"
    parsed, fixed = parse([f"{key}={value}" for key, value in sweeper.params.items()])
    assert fixed == [] and {name: dist for name, (_, dist) in parsed.items()} == expected
    # the fixed PPO values of Table A3
    fixed_values = ("gamma", "critic_coeff", "max_grad_norm", "clip_value", "clip_epsilon")
    assert [cfg.agent[key] for key in fixed_values] == [0.99, 0.1, 1.0, 0.2, 0.2]


def test_sweep_syntax_becomes_optuna_distributions():
    space, fixed = parse(
        [
            "a=choice(1, 2.5, fd)",
            "b=range(1, 10, 3)",
            "c=tag(log, int, interval(1, 100))",
            "d=tag(log, interval(1e-4, 1e-2))",
            "+e.f=true,false",
            "g=5",
            "+exp=find_ppo",
            "b=7",  # a later plain value fixes a searched key
        ]
    )
    assert {name: dist for name, (_, dist) in space.items()} == {
        "a": CategoricalDistribution([1, 2.5, "fd"]),
        "c": IntDistribution(1, 100, log=True),
        "d": FloatDistribution(1e-4, 1e-2, log=True),
        "e.f": CategoricalDistribution([True, False]),
    }
    assert space["e.f"][0] == "+e.f" and fixed == ["g=5", "+exp=find_ppo", "b=7"]
    assert parse(["b=range(1, 10, 3)"])[0]["b"][1] == IntDistribution(1, 7, step=3)
    with pytest.raises(ValueError, match="unknown tag"):
        parse(["a=tag(cube, interval(1, 2))"])
    with pytest.raises(ValueError, match="choices must be"):
        parse(["a=choice([1, 2], [3])"])
    with pytest.raises(ValueError, match="sets run_dir for each trial"):
        parse(["a=1,2", "run_dir=/tmp/x"])
    # sampled values go back to Hydra as text that reads as the same value
    parser = OverridesParser.create()
    for value in (1, 0.5, 1e-05, math.inf, True, None, "fd", "a b", "1e-3", "it's", "/tmp/x-1/y.z"):
        assert parser.parse_override(f"k={render(value)}").value() == value


def test_storage_urls(tmp_path):
    with pytest.raises(ValueError, match="unknown kind"):
        open_storage("redis://localhost/0")
    with pytest.raises(ValueError, match="unknown kind"):
        open_storage("study.db")
    assert redact("postgresql://me:secret@db:5432/optuna") == "postgresql://me:***@db:5432/optuna"
    journal = f"journal://{tmp_path}/journal/study.log"  # the alternative for a shared file system
    optuna.create_study(storage=open_storage(journal), study_name="s").optimize(lambda t: 1.0, n_trials=1)
    assert load_study(tmp_path, storage=journal, study_name="s").best_value == 1.0
    with pytest.raises(FileNotFoundError, match="no sweep directory"):
        load_study(tmp_path / "missing")
    with pytest.raises(FileNotFoundError, match="give --storage and --study"):
        load_study(tmp_path)


@pytest.mark.slow  # end to end: Hydra's launcher or sweeper starts training processes
def test_tiny_sweep_survives_a_nan_trial_and_writes_the_best_config(tmp_path, capsys):
    sweep_dir = tmp_path / "sweep"
    # the reward scale is searched too: its inf choice makes a trial's returns inf (seed 1: trials 1, 3)
    done = sweep(
        f"hydra.sweep.dir={sweep_dir}",
        "hydra.sweeper.n_trials=3",
        "hydra.sweeper.seed=1",
        "+env.overrides.reward_scales.dist=choice(1.0, 1e308)",
    )
    assert done.returncode == 0, done.stderr[-3000:]
    study = load_study(sweep_dir)
    assert study.study_name == "find_ppo-ppo"
    trials = study.get_trials()
    states = [t.state for t in trials]
    assert states.count(TrialState.COMPLETE) == 3 and TrialState.FAIL in states
    assert TrialState.RUNNING not in states
    storage = f"sqlite:///{sweep_dir / 'study.db'}"
    for trial in trials:  # trial <-> run directory, both ways
        run_dir = sweep_dir / "trials" / str(trial.number)
        assert trial.user_attrs["run_dir"] == str(run_dir)
        link = json.loads((run_dir / "trial.json").read_text())
        assert link == {
            "study_name": "find_ppo-ppo",
            "storage": storage,
            "trial_number": trial.number,
            "params": trial.params,
        }
        if trial.state == TrialState.FAIL:
            # 1e308 is a finite scale, but the returns overflow to inf
            assert trial.params["env.overrides.reward_scales.dist"] == 1e308
            assert "NaN or inf" in trial.user_attrs["fail_reason"]
            assert "NonFiniteError" in (run_dir / "error.txt").read_text()
        else:
            assert trial.value == pytest.approx(run_objective(run_dir))
    summary = (sweep_dir / "summary.md").read_text()
    assert f"## Best trial: {study.best_trial.number}" in summary and "NaN or inf" in summary
    assert all((sweep_dir / f"{plot}.png").is_file() for plot in ("history", "params"))
    # three complete trials are too few for importances: said, not plotted
    assert "needs at least 10 complete trials, has 3" in summary
    assert not (sweep_dir / "importance.png").exists()

    conf_dir = tmp_path / "conf"
    assert sweep_main(["best", str(sweep_dir), "--conf-dir", str(conf_dir), "--seeds", "2"]) == 0
    printed = capsys.readouterr().out
    assert f"+exp=find_ppo_ppo_best seed=0,1 'hydra.searchpath=[file://{conf_dir}]'" in printed
    with initialize_config_dir(str(resource_dir("conf")), version_base="1.3"):
        cfg = compose("train", overrides=["exp=find_ppo_ppo_best", f"hydra.searchpath=[file://{conf_dir}]"])
    assert cfg.exp_name == "find_ppo_ppo_best" and cfg.env.task == "find" and cfg.env.num_envs == 4096
    assert cfg.agent.lr == study.best_params["agent.lr"] and cfg.env.overrides.reward_scales.dist == 1.0
    with pytest.raises(SystemExit, match="exists; pick another --name or pass --force"):
        sweep_main(["best", str(sweep_dir), "--conf-dir", str(conf_dir)])
    assert sweep_main(["best", str(sweep_dir), "--conf-dir", str(conf_dir), "--force", "+profile=smoke"]) == 0
    assert capsys.readouterr().out.rstrip().endswith(f"'hydra.searchpath=[file://{conf_dir}]' +profile=smoke")


@pytest.mark.slow  # end to end: Hydra's launcher or sweeper starts training processes
def test_failing_trials_stop_the_sweep_after_max_failures(tmp_path):
    failed = sweep(
        f"hydra.sweep.dir={tmp_path}",
        "hydra.sweeper.max_failures=2",
        "+env.overrides.reward_scales.dist=choice(inf)",
    )
    assert failed.returncode == 1 and "2 trials in a row failed" in failed.stderr
    assert "Traceback" not in failed.stderr
    assert [t.state for t in load_study(tmp_path).get_trials()] == [TrialState.FAIL] * 2


@pytest.mark.slow  # end to end: Hydra's launcher or sweeper starts training processes
def test_killed_sweep_resumes_with_the_same_command(tmp_path):
    args = [*TINY_SWEEP, f"hydra.sweep.dir={tmp_path}", "hydra.sweeper.n_trials=3"]
    proc = subprocess.Popen([*TRAIN, *args], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    started = tmp_path / "trials" / "1" / "trial.json"  # trial 0 is complete, trial 1 running
    deadline = time.time() + 240
    while time.time() < deadline and not started.exists() and proc.poll() is None:
        time.sleep(0.1)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert started.exists(), "trial 1 never started"
    before = load_study(tmp_path).get_trials()
    assert [t.state for t in before] == [TrialState.COMPLETE, TrialState.RUNNING]

    done = subprocess.run([*TRAIN, *args], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "trial 1 was left RUNNING by dead worker" in done.stdout
    after = load_study(tmp_path).get_trials()
    complete, fail = TrialState.COMPLETE, TrialState.FAIL
    assert [t.state for t in after] == [complete, fail, complete, complete]
    assert after[0].value == before[0].value and after[0].params == before[0].params  # kept, not rerun
    reason = after[1].user_attrs["fail_reason"]
    assert reason.startswith("its worker") and reason.endswith("died")
    assert not (tmp_path / "trials" / "1" / "summary.json").exists()


# ---------------------------------------------------------------------------- PostgreSQL, two workers


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture
def postgresql_url():
    """A throw-away PostgreSQL server on a unix socket in /tmp; yields its SQLAlchemy URL."""
    binaries = {name: shutil.which(name) for name in ("initdb", "pg_ctl", "postgres")}
    missing = [name for name, path in binaries.items() if path is None]
    if missing:
        pytest.skip(f"PostgreSQL binaries not on PATH: {missing}")
    pytest.importorskip("psycopg", reason="no PostgreSQL driver: pip install 'psycopg[binary]' (dev extra)")
    as_user: list[str] = []
    base = Path(tempfile.mkdtemp(prefix="roto-pg-"))  # short: a socket path must stay under 108 bytes
    if os.geteuid() == 0:  # PostgreSQL refuses to run as root
        try:
            owner = pwd.getpwnam("postgres")
        except KeyError:
            shutil.rmtree(base)
            pytest.skip("running as root and there is no 'postgres' user to run the server as")
        os.chown(base, owner.pw_uid, owner.pw_gid)
        as_user = ["runuser", "-u", "postgres", "--"]
    data, port = base / "data", _free_port()
    options = f"-p {port} -k {base} -c listen_addresses=''"

    def run(*args):
        subprocess.run([*as_user, *map(str, args)], check=True, capture_output=True, timeout=120)

    try:
        initdb = [binaries["initdb"], "-D", data, "-U", "roto", "--auth=trust", "--no-sync"]
        run(*initdb, "--locale=C", "-E", "UTF8")  # not the C locale's SQL_ASCII: psycopg would read bytes
        run(binaries["pg_ctl"], "-D", data, "-l", base / "server.log", "-w", "-o", options, "start")
        yield f"postgresql://roto@/postgres?host={base}&port={port}"
    finally:
        if (data / "postmaster.pid").exists():
            run(binaries["pg_ctl"], "-D", data, "-m", "immediate", "stop")
        shutil.rmtree(base, ignore_errors=True)


@pytest.mark.slow
def test_two_workers_share_a_postgresql_study(tmp_path, postgresql_url):
    n_trials = 6
    # the same command on both workers, started at once
    args = [
        *TINY_SWEEP,
        f"hydra.sweep.dir={tmp_path}",
        f"hydra.sweeper.n_trials={n_trials}",
        f"hydra.sweeper.storage='{postgresql_url}'",
    ]
    command = [*TRAIN, *args]
    workers = [
        subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        for _ in range(2)
    ]
    outputs = [worker.communicate(timeout=600)[0] for worker in workers]
    for worker, output in zip(workers, outputs, strict=True):
        assert worker.returncode == 0, output[-3000:]
    trials = load_study(tmp_path, storage=postgresql_url).get_trials()
    # each worker checks the count before it starts a trial: at most workers - 1 past the target
    assert n_trials <= len(trials) <= n_trials + 1
    assert all(t.state == TrialState.COMPLETE for t in trials)
    numbers = [t.number for t in trials]
    assert numbers == list(range(len(trials)))  # unique, none lost
    assert sorted(int(p.name) for p in (tmp_path / "trials").iterdir()) == numbers
    for trial in trials:
        run_dir = Path(trial.user_attrs["run_dir"])
        assert json.loads((run_dir / "trial.json").read_text())["trial_number"] == trial.number
        assert trial.value == pytest.approx(run_objective(run_dir))
    assert len({t.user_attrs["worker"] for t in trials}) == 2  # both workers ran trials


@pytest.mark.slow  # end to end: Hydra's launcher or sweeper starts training processes
def test_bad_sweep_setups_get_one_line(tmp_path):
    (tmp_path / "study.db").write_text("not a database")
    corrupt = sweep(f"hydra.sweep.dir={tmp_path}")
    assert corrupt.returncode == 2 and "Traceback" not in corrupt.stderr
    assert (
        f"storage sqlite:///{tmp_path}/study.db cannot be opened (file is not a database)" in corrupt.stderr
    )
    all_fixed = sweep(f"hydra.sweep.dir={tmp_path / 'fixed'}", "agent.lr=1e-4")
    assert all_fixed.returncode == 2 and "Traceback" not in all_fixed.stderr
    assert "the command line fixes every key of the search space" in all_fixed.stderr
    (tmp_path / "study.json").write_text("{bad")
    with pytest.raises(SystemExit, match=f"{tmp_path}/study.json is not valid JSON"):
        sweep_main(["summary", str(tmp_path)])


@pytest.mark.slow  # end to end: Hydra's launcher or sweeper starts training processes
def test_sweep_runs_two_trials_at_once_through_joblib(tmp_path):
    done = sweep(
        f"hydra.sweep.dir={tmp_path}",
        "hydra.sweeper.n_trials=3",
        "hydra.sweeper.n_jobs=2",
        "hydra/launcher=joblib",
        "hydra.launcher.n_jobs=2",
    )
    assert done.returncode == 0, done.stderr[-3000:]
    trials = load_study(tmp_path).get_trials()
    assert [t.state for t in trials] == [TrialState.COMPLETE] * 3
    runs = [tmp_path / "trials" / str(n) for n in range(3)]
    for trial, run_dir in zip(trials, runs, strict=True):
        assert trial.value == pytest.approx(run_objective(run_dir))
    # trials 0 and 1 were one batch: each started (config.yaml) before the other ended (summary.json)
    start = [(run / "config.yaml").stat().st_mtime for run in runs]
    end = [(run / "summary.json").stat().st_mtime for run in runs]
    assert start[0] < end[1] and start[1] < end[0]
    assert start[2] > max(end[:2])  # the third trial waited for a free slot: the target is 3


# ---------------------------------------------------------------------------- faults of sweeps and multiruns


@pytest.mark.slow  # end to end: Hydra's sweeper
def test_a_sweep_directory_it_cannot_write_is_one_line():
    done = sweep("hydra.sweep.dir=/proc/roto-sweep")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "sweep: hydra.sweep.dir=/proc/roto-sweep is not writable" in done.stderr


@pytest.mark.slow  # end to end: a sweep process stopped by Ctrl-C
def test_ctrl_c_of_a_sweep_exits_130_with_one_line(tmp_path):
    args = [*TINY_SWEEP, f"hydra.sweep.dir={tmp_path}", "total_frames=100000"]
    proc = subprocess.Popen([*TRAIN, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    started = tmp_path / "trials" / "0" / "train.csv"
    deadline = time.time() + 240
    while time.time() < deadline and not started.exists():
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=240)
    assert proc.returncode == 130 and "Traceback" not in err, err[-2000:]
    assert "sweep: interrupted; the trials that were running are marked FAIL (interrupted)" in err
    assert [t.state for t in load_study(tmp_path).get_trials()] == [TrialState.FAIL]


@pytest.mark.slow  # end to end: two jobs through the joblib launcher
def test_every_failed_job_of_a_multirun_is_reported_with_its_error_file(tmp_path):
    nan = "+env.overrides.reward_scales.dist=1e308"  # the first rollout's returns are inf
    args = [
        "-m",
        "+exp=find_ppo",
        *TINY,
        "seed=0,1",
        nan,
        "hydra/launcher=joblib",
        f"hydra.sweep.dir={tmp_path}",
    ]
    done = subprocess.run([*TRAIN, *args], capture_output=True, text=True, timeout=300)
    assert done.returncode == 1
    failed = sorted(tmp_path.glob("*-find_ppo-s*"))
    assert len(failed) == 2
    for run in failed:
        assert "NonFiniteError" in (run / "error.txt").read_text()
        assert f"train: the job in {run} failed: NonFiniteError" in done.stderr


def test_a_trial_whose_run_finished_is_kept_when_its_worker_died(tmp_path):
    """A RUNNING trial of a dead worker: COMPLETE with its run's objective when the run finished
    (summary.json), FAIL when it had not."""
    from hydra_plugins.roto_optuna_sweeper._study import StudyLoop

    study = optuna.create_study(direction="maximize", storage=f"sqlite:///{tmp_path / 'study.db'}")
    runs = {}
    for number, finished in ((0, True), (1, False)):
        trial = study.ask()
        run = tmp_path / "trials" / str(number)
        run.mkdir(parents=True)
        (run / "config.yaml").write_text("exp_name: find_ppo\nseed: 0\nenv:\n  task: find\n")
        (run / "eval.csv").write_text("frames,return_mean,reached_3cm\n100,5,0.25\n200,6,0.75\n")
        if finished:
            (run / "summary.json").write_text("{}")
        trial.set_user_attr("run_dir", str(run))
        trial.set_user_attr("worker", f"{socket.gethostname()}:999999999")  # no such process
        runs[number] = trial
    loop = StudyLoop.__new__(StudyLoop)  # the one method, without a Hydra sweeper around it
    loop.study, loop.storage = study, study._storage
    loop.study_id = study._study_id
    loop.conf = type("Conf", (), {"objective": "headline"})()
    loop.fail_dead_trials()
    done, lost = study.get_trials()
    assert (done.state, done.value) == (TrialState.COMPLETE, 0.5)  # reached_3cm over the last evaluations
    assert lost.state == TrialState.FAIL and "died" in lost.user_attrs["fail_reason"]
