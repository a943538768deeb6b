"""PPO training through roto_trl/train.py: configs, smoke runs, determinism, resume, NaN stop."""

import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from helpers import OPENMP_DEFAULTS, TINY, TRAIN, compose_cfg
from omegaconf import OmegaConf

from roto_trl.analysis.checkpoint_eval import evaluate_run
from roto_trl.modules.normalization import ValueNormalizer
from roto_trl.train import train
from roto_trl.trainers.builders import agent_for_env, make_train_env
from roto_trl.trainers.checkpoint import load_checkpoint
from roto_trl.trainers.errors import NonFiniteError
from roto_trl.utils.resources import resource_dir

FRAMES_PER_ITERATION = 8 * 16  # TINY: 8 worlds x 16 steps
# Table A4's 21 experiments and the 3 no-last-action ablations (conf/exp/ may hold more: tuned sweeps)
VARIANTS = ("ppo_prop", "ppo", "ppo_prop_nolastaction", "fr", "tr", "fd", "tfd", "fd_mem")
EXPS = [f"{task}_{variant}" for task in ("find", "bounce", "baoding") for variant in VARIANTS]
# one training run per distinct code path: each task, each observation set, each SSL objective,
# the memory, and the CPU profile (separate critic, weight decay, KL rule); the composition of
# every experiment is checked without training
PATHS = {
    "find_tr": [],
    "bounce_fr": ["logger.aux_minibatches=true"],
    "baoding_tfd": ["ssl.seq_len=4"],
    "bounce_fd_mem": [
        "ssl.seq_len=4",
        "profile=cpu",
        "agent.precision=float32",
        "agent.min_rollout_len=null",
    ],
    "find_ppo_prop_nolastaction": [],
    "baoding_ppo_prop": [],
}


def rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def test_the_script_sets_openmp_waiting_before_torch_loads(tmp_path):
    """``python roto_trl/train.py`` imports the package (which sets the OpenMP defaults) before
    torch: OpenMP reads them once, when torch loads it."""
    code = (
        "import os, runpy, sys\n"
        "seen = []\n"
        "class Spy:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'torch' and not seen:\n"
        f"            seen.append(tuple(os.environ.get(k) for k in {list(OPENMP_DEFAULTS)}))\n"
        "sys.meta_path.insert(0, Spy())\n"
        f"runpy.run_path({TRAIN[1]!r}, run_name='not_main')\n"
        f"assert seen == [{tuple(OPENMP_DEFAULTS.values())}], seen\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in OPENMP_DEFAULTS}
    subprocess.run([sys.executable, "-c", code], check=True, env=env, cwd=tmp_path)


def test_every_experiment_has_its_config():
    assert {f"{exp}.yaml" for exp in EXPS} <= {p.name for p in (resource_dir("conf") / "exp").glob("*.yaml")}


@pytest.mark.parametrize("exp", EXPS)
def test_every_experiment_composes_with_the_papers_defaults(exp):
    cfg = compose_cfg([f"+exp={exp}"])
    task, variant = exp.split("_", 1)
    assert cfg.env.task == task and cfg.exp_name == exp
    assert cfg.env.num_envs == 4096
    assert cfg.total_frames == (250_000_000 if task == "baoding" else 200_000_000)
    prop_only = variant.startswith("ppo_prop")
    assert list(cfg.env.obs_keys) == (["prop"] if prop_only else ["prop", "tactile"])
    assert cfg.env.last_action == (not variant.endswith("nolastaction"))
    ssl = {"fd_mem": "fd"}.get(variant, variant if variant in ("tr", "fr", "fd", "tfd") else "none")
    assert cfg.ssl.name == ssl
    if variant == "fd_mem":
        assert cfg.ssl.memory_rollouts >= 2
    assert cfg.logger.backend == "wandb"


def test_obs_keys_and_last_action_set_the_encoder_input():
    sizes = {}
    for exp in ("find_ppo", "find_ppo_prop", "find_ppo_prop_nolastaction"):
        cfg = compose_cfg([f"+exp={exp}", "env.num_envs=2"])
        env = make_train_env(cfg)
        sizes[exp] = agent_for_env(cfg, env).encoder.obs_dim
        env.close()
    assert sizes == {"find_ppo": 16 * 37, "find_ppo_prop": 16 * 35, "find_ppo_prop_nolastaction": 16 * 26}


@pytest.mark.parametrize("exp", PATHS)
def test_a_smoke_run_of_each_code_path_writes_its_run_directory(exp, tmp_path):
    task = exp.split("_")[0]
    run = tmp_path / exp
    # runs of n <= 4 steps: TINY's short random episodes always hold some (n = 10 needs longer ones)
    tiny = [o for o in TINY if not o.startswith("+profile")] if "profile=cpu" in PATHS[exp] else TINY
    overrides = [f"+exp={exp}", *tiny, *PATHS[exp], "total_frames=512", f"run_dir={run}"]
    summary_path = train(compose_cfg(overrides))
    summary = json.loads(summary_path.read_text())
    assert summary["frames"] == 512 and summary["iterations"] == 4
    assert 0 < summary["eval_share"] < 1 and summary["eval_time_s"] > 0  # evaluation's part of the wall time
    assert summary["final_eval"] is not None and "return_mean" in summary["final_eval"]
    metric = {"find": "find_time_3cm", "bounce": "bounces", "baoding": "rotations"}[task]
    assert metric in summary["final_eval"]
    assert [int(r["frames"]) for r in rows(run / "train.csv")] == [128, 256, 384, 512]
    assert [int(r["frames"]) for r in rows(run / "eval.csv")] == [0, 256, 512]  # start, every 256 frames
    assert 0 < float(rows(run / "train.csv")[-1]["time/eval_share"]) < 1
    assert (run / "config.yaml").is_file() and (run / "plots" / "eval.png").is_file()
    assert json.loads((run / "eval.json").read_text())["physical"]  # the best checkpoint's metrics
    index = (run / "index.md").read_text()
    assert "![evaluation](plots/eval.png)" in index and "| metric | what | unit | value |" in index
    assert ".lock" not in index and "time_s" in json.loads((run / "summary.json").read_text())["final_eval"]
    state = load_checkpoint(run)
    assert state["frames"] == 512 and "value_norm.mean" in "".join(state["agent"])
    assert (run / "checkpoints" / "best.pt").is_file()
    cfg = OmegaConf.load(run / "config.yaml")
    if cfg.ssl.name == "none":
        assert not (run / "aux.csv").exists() and "aux" not in state
    elif "logger.aux_minibatches=true" in PATHS[exp]:  # one row per minibatch: 4 iterations x 2 x 2
        aux = rows(run / "aux.csv")
        assert len(aux) == 16 and all(math.isfinite(float(r["aux_loss"])) for r in aux)
        assert "optimizer" in state["aux"]
    else:  # the auxiliary numbers' means per iteration only: a few columns of train.csv
        assert not (run / "aux.csv").exists() and "aux/aux_loss" in rows(run / "train.csv")[0]


def test_same_seed_gives_identical_metrics(tmp_path):
    tables = []
    for name in ("a", "b"):
        train(compose_cfg(["+exp=bounce_ppo", *TINY, f"run_dir={tmp_path / name}", "seed=5"]))
        table = rows(tmp_path / name / "train.csv")
        timing = ("time/", "fps", "wall")
        tables.append([{k: v for k, v in r.items() if not k.startswith(timing)} for r in table])
    assert tables[0] == tables[1]
    assert float(tables[0][0]["loss_critic"]) != 0.0


def test_value_norm_off_trains_the_value_head_on_raw_returns(tmp_path):
    norm = ValueNormalizer(enabled=False)
    returns = torch.tensor([3.0, 40.0, -7.0])
    norm.update(returns)
    assert torch.equal(norm.normalize(returns), returns) and torch.equal(norm.denormalize(returns), returns)
    counts = {}
    for value_norm in ("true", "false"):
        run = tmp_path / value_norm
        train(compose_cfg(["+exp=bounce_ppo", *TINY, f"run_dir={run}", f"agent.value_norm={value_norm}"]))
        counts[value_norm] = float(load_checkpoint(run)["agent"]["value_norm.count"])
    # on: every return of the 256 frames counted; off: the statistics never move
    assert counts == {"true": pytest.approx(256 + 1e-4), "false": pytest.approx(1e-4)}


def test_cli_rejects_bad_overrides_with_clear_errors(tmp_path):
    bad_key = subprocess.run([*TRAIN, "+exp=find_ppo", "env.num_env=3"], capture_output=True, text=True)
    assert bad_key.returncode != 0 and "num_env" in bad_key.stderr and "Traceback" not in bad_key.stderr
    # one of ours, as a user meets it: one line on stderr, exit status 2
    out = subprocess.run(
        [*TRAIN, "+exp=find_ppo", "+agent.lrr=1e-3", f"run_dir={tmp_path}"], capture_output=True, text=True
    )
    message = "train: agent.lrr is not a config key; did you mean agent.lr? (the keys: docs/keys.md)"
    assert out.returncode == 2 and out.stderr.strip().splitlines() == [message]
    with pytest.raises(ValueError, match=r"^env\.num_envs must be >= 1, got 0$"):  # the others, in process
        train(compose_cfg(["+exp=find_ppo", "env.num_envs=0", f"run_dir={tmp_path}"]))
    assert not list(tmp_path.iterdir())  # refused before anything was written
    with pytest.raises(Exception, match="find_ppo"):  # Hydra's error lists the experiments
        compose_cfg(["+exp=find_dqn"])


def test_resume_after_sigkill_continues_frames_and_optimiser(tmp_path):
    run = tmp_path / "run"
    args = ["+exp=find_ppo", *TINY, "total_frames=100000", f"run_dir={run}", "checkpoint.interval_minutes=0"]
    proc = subprocess.Popen([*TRAIN, *args], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    latest = run / "checkpoints" / "latest.pt"
    deadline = time.time() + 240
    while time.time() < deadline and not latest.exists():
        time.sleep(0.5)
    time.sleep(1.0)  # a few more iterations
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert latest.exists(), "no checkpoint before the kill"
    killed = load_checkpoint(run)
    frames_at_kill = killed["frames"]
    assert 0 < frames_at_kill < 100_000
    adam_steps = max(int(s["step"]) for s in killed["optimizer"]["state"].values())

    # finish it: the same run directory, a few iterations past the checkpoint
    config = OmegaConf.load(run / "config.yaml")
    config.total_frames = frames_at_kill + 2 * FRAMES_PER_ITERATION
    OmegaConf.save(config, run / "config.yaml")
    done = subprocess.run([*TRAIN, f"resume={run}"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"resuming {run}" in done.stdout
    final = load_checkpoint(run)
    assert final["frames"] == frames_at_kill + 2 * FRAMES_PER_ITERATION
    # 2 more iterations x 2 epochs x 2 minibatches of Adam steps, continuing the saved count
    assert max(int(s["step"]) for s in final["optimizer"]["state"].values()) == adam_steps + 2 * 2 * 2
    frames = [int(r["frames"]) for r in rows(run / "train.csv")]
    assert frames[-2:] == [frames_at_kill + FRAMES_PER_ITERATION, frames_at_kill + 2 * FRAMES_PER_ITERATION]
    norm_before, norm_after = killed["agent"]["value_norm.count"], final["agent"]["value_norm.count"]
    assert float(norm_after) == pytest.approx(float(norm_before) + 2 * FRAMES_PER_ITERATION)


def test_kl_adaptive_lr_is_logged_and_restored_on_resume(tmp_path):
    run = tmp_path / "run"
    # a target no KL stays under: the rate divides by 1.5 after each of the 2 epochs per iteration
    schedule = ["agent.lr_schedule=kl_adaptive", "agent.kl_target=1e-12", "agent.lr=1e-3"]
    train(compose_cfg(["+exp=bounce_ppo", *TINY, *schedule, "total_frames=256", f"run_dir={run}"]))
    table = rows(run / "train.csv")
    assert [float(r["lr"]) for r in table] == pytest.approx([1e-3 / 1.5**2, 1e-3 / 1.5**4])
    assert all(float(r["kl_k3_median"]) > 0 for r in table)
    assert {"kl_approx_median", "clip_fraction_median", "kl_approx", "clip_fraction"} <= set(table[0])
    assert load_checkpoint(run)["optimizer"]["param_groups"][0]["lr"] == pytest.approx(1e-3 / 1.5**4)
    config = OmegaConf.load(run / "config.yaml")
    config.total_frames = 512
    OmegaConf.save(config, run / "config.yaml")
    train(compose_cfg([f"resume={run}"]))
    lrs = [float(r["lr"]) for r in rows(run / "train.csv")]
    assert lrs == pytest.approx([1e-3 / 1.5 ** (2 * i) for i in (1, 2, 3, 4)])  # continues, not restarts


def test_resume_restores_both_optimisers_of_an_ssl_run(tmp_path):
    run = tmp_path / "run"
    train(compose_cfg(["+exp=bounce_fd", *TINY, "ssl.seq_len=4", "total_frames=256", f"run_dir={run}"]))
    state = load_checkpoint(run)

    def adam_steps(optimizer_state):
        return {int(s["step"]) for s in optimizer_state["state"].values()}

    # 2 iterations x 2 epochs x 2 minibatches: every step moves both optimisers once
    assert adam_steps(state["optimizer"]) == adam_steps(state["aux"]["optimizer"]) == {8}
    config = OmegaConf.load(run / "config.yaml")
    config.total_frames = 512
    OmegaConf.save(config, run / "config.yaml")
    train(compose_cfg([f"resume={run}"]))
    state = load_checkpoint(run)
    assert adam_steps(state["optimizer"]) == adam_steps(state["aux"]["optimizer"]) == {16}


def test_the_policy_encoders_latent_rank_is_logged_in_training_evaluations_and_evaluate(tmp_path):
    run = tmp_path / "run"
    train(compose_cfg(["+exp=find_ppo", *TINY, f"run_dir={run}"]))
    trained, evaluated = rows(run / "train.csv"), rows(run / "eval.csv")
    assert len(trained) == 2 and len(evaluated) == 2  # the untrained policy's and the final
    assert all(1.0 < float(r["latent_rank"]) <= 256 for r in trained + evaluated)
    result = json.loads(evaluate_run(run, "latest", out=tmp_path / "e.json").read_text())
    assert result["latent_rank"] == pytest.approx(float(evaluated[-1]["latent_rank"]), rel=1e-5)


def test_nan_stops_the_run_and_keeps_the_last_good_checkpoint(tmp_path):
    run = tmp_path / "run"
    train(compose_cfg(["+exp=find_ppo", *TINY, "total_frames=128", f"run_dir={run}"]))
    latest = run / "checkpoints" / "latest.pt"
    good = latest.read_bytes()
    # the run continues with a reward that overflows: returns become inf
    config = OmegaConf.load(run / "config.yaml")
    config.total_frames = 1024
    config.env.overrides.reward_scales = {"dist": 1e308}  # finite, but the returns overflow to inf
    OmegaConf.save(config, run / "config.yaml")
    with pytest.raises(NonFiniteError, match="NaN or inf"):
        train(compose_cfg([f"resume={run}"]))
    assert latest.read_bytes() == good
    params = load_checkpoint(run)["agent"].values()
    assert torch.isfinite(torch.stack([p.float().sum() for p in params])).all()


def test_record_plays_a_trained_checkpoint(tmp_path):
    from roto_trl.record import main as record_main

    run = tmp_path / "run"
    train(compose_cfg(["+exp=find_ppo_prop", *TINY, "total_frames=128", f"run_dir={run}"]))
    out = tmp_path / "find.mp4"
    try:
        record_main(["task=find", f"policy={run}/checkpoints/best.pt", f"out={out}", "max_steps=5"])
    except SystemExit as err:
        if "no OpenGL context" in str(err):
            pytest.skip(f"no offscreen OpenGL on this machine: {err}")
        raise
    assert out.stat().st_size > 0
    with pytest.raises(SystemExit, match="trained on 'find', not task=bounce"):
        record_main(["task=bounce", f"policy={run}/checkpoints/best.pt", f"out={out}"])


@pytest.mark.parametrize("backend", ["wandb", "tensorboard", "csv", "none"])
def test_logger_backends_work_offline(backend, tmp_path, monkeypatch):
    from roto_trl.trainers.loggers import MetricLogger, read_csv

    monkeypatch.setenv("WANDB_MODE", "offline")  # belt and braces: never reach for the network
    logger = MetricLogger(tmp_path, backend, config={"seed": 0}, name="t")
    logger.log("eval", {"return_mean": 1.5}, 100)
    logger.log("eval", {"return_mean": 2.5}, 200)
    logger.close()
    assert read_csv(tmp_path / "eval.csv") == {"frames": [100.0, 200.0], "return_mean": [1.5, 2.5]}
    if backend == "wandb":
        assert list((tmp_path / "wandb").glob("offline-run-*"))
    if backend == "tensorboard":
        assert list((tmp_path / "tensorboard").glob("events.out.tfevents.*"))
