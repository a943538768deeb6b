"""PPO on a RoTO task: ``python roto_trl/train.py +exp=<task>_<variant> [key=value ...]``.

    python roto_trl/train.py +exp=find_ppo                         # the paper's Find PPO(prop-tactile)
    python roto_trl/train.py +exp=bounce_ppo_prop +profile=smoke   # a real run in under two minutes
    python roto_trl/train.py resume=runs/find_ppo/20261122-101500-s0   # continue a killed run

Reads top to bottom: build the envs, the agent, the PPO loss and advantage, the collector and
the rollout buffer; then the loop: collect a rollout of every world, estimate advantages, update,
evaluate every ``eval.every_frames`` frames, log, checkpoint. Everything of a run lands in its
own directory: ``config.yaml``, ``train.csv``, ``eval.csv``, ``checkpoints/{latest,best}.pt``,
``plots/`` and ``summary.json``. ``best.pt`` is the evaluation with the highest headline metric
(Find: fraction within 3 cm; Bounce, Baoding: bounces, rotations per 10 s), the return breaking
ties (``selection_key``).
"""

from __future__ import annotations

import json
import logging
import os
import random
import signal
import sys
import time
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path

import roto_trl  # noqa: F401  first, before torch loads: sets how its OpenMP threads wait (roto_trl/__init__.py)

# isort: split
import hydra
import numpy as np
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf, open_dict

from roto_trl.analysis.checkpoint_eval import evaluate_run
from roto_trl.analysis.plots import plot_run
from roto_trl.envs.factory import task_config
from roto_trl.modules.agent import checked_critic_sizes
from roto_trl.modules.distributions import (
    DEFAULT_ACTION_LOG_PROB,
    DEFAULT_DETERMINISTIC_ACTION,
    policy_distribution_kwargs,
)
from roto_trl.modules.networks import cpu_has_bfloat16, on_cpu
from roto_trl.objectives.mean_bound import checked_mean_bound
from roto_trl.objectives.proximal_feature import checked_feature_coeff
from roto_trl.trainers.builders import (
    ADAM_BETAS,
    ADAM_EPS,
    adam_betas,
    adam_eps,
    advantage_norm_scope,
    agent_for_env,
    agent_precision,
    apply_precision,
    apply_rollout_floor,
    compile_agent,
    eval_seed,
    gae_horizon,
    log_std_lr,
    make_advantage,
    make_aux_update,
    make_collector,
    make_eval_env,
    make_lr_schedule,
    make_optimizer,
    make_policy_average,
    make_policy_terms,
    make_ppo_loss,
    make_rollout_buffer,
    make_std_ceiling,
    make_train_env,
    weight_decay,
    weight_decay_parts,
)
from roto_trl.trainers.checkpoint import BEST, LATEST, load_checkpoint, save_checkpoint
from roto_trl.trainers.errors import NonFiniteError, RunInUse, TrainingInterrupted, WriteError
from roto_trl.trainers.evaluation import evaluate, selection_key
from roto_trl.trainers.interrupts import StopRequests
from roto_trl.trainers.loggers import BACKENDS, MetricLogger, read_csv
from roto_trl.trainers.policy_average import POLICY_AVERAGE_KEY, averaged, checked_decay
from roto_trl.trainers.ppo import minibatch_keys, ppo_update, rollout_stats, store_rollout
from roto_trl.trainers.progress import TrainingProgress
from roto_trl.trainers.run_dir import finished_reason, resume_config, rewind
from roto_trl.trainers.run_lock import RunLock
from roto_trl.trainers.schedule import (
    EvalClock,
    eval_every_frames,
    evaluation_due,
    evaluations_left,
    frames_per_iteration,
)
from roto_trl.trainers.std_ceiling import DEFAULT_FRAMES, checked_std_ceiling
from roto_trl.trainers.threads import job_threads
from roto_trl.utils.cli import is_number, positive_int_or_null
from roto_trl.utils.paths import writable_dir
from roto_trl.utils.resources import resource_dir

EXIT_NON_FINITE = 3  # exit status of a run stopped by a NaN or inf


# ---------------------------------------------------------------------------- run setup


def check_config(cfg: DictConfig) -> None:
    """One-line errors for values Hydra cannot check (types and keys it checks itself)."""
    positive = {
        "env.num_envs": cfg.env.num_envs,
        "eval.num_envs": cfg.eval.num_envs,
        "total_frames": cfg.total_frames,
        "agent.rollout_len": cfg.agent.rollout_len,
        "agent.minibatches": cfg.agent.minibatches,
        "agent.epochs": cfg.agent.epochs,
    }
    for key, value in positive.items():
        if not isinstance(value, int) or value < 1:
            raise ValueError(f"{key} must be a positive integer, got {value!r}")
    eval_every_frames(cfg)  # a positive integer; the old eval.interval gets the equivalent value
    if frames_per_iteration(cfg) < cfg.agent.minibatches:
        raise ValueError("agent.minibatches exceeds one rollout's frames (env.num_envs * agent.rollout_len)")
    limit = cfg.time_limit_minutes
    if limit is not None and not (is_number(limit) and limit > 0):
        raise ValueError(f"time_limit_minutes must be > 0 or null, got {cfg.time_limit_minutes!r}")
    if not float(cfg.agent.lr) > 0:
        raise ValueError(f"agent.lr must be > 0, got {cfg.agent.lr}")
    a = cfg.agent
    if not (is_number(a.entropy_coeff) and a.entropy_coeff >= 0):
        raise ValueError(f"agent.entropy_coeff must be a number >= 0 (e.g. 0.05), got {a.entropy_coeff!r}")
    if a.clip_value is not None and not (is_number(a.clip_value) and a.clip_value > 0):
        raise ValueError(f"agent.clip_value must be > 0 or null (no value clipping), got {a.clip_value!r}")
    checked_mean_bound(a.get("mean_bound"), a.get("mean_bound_coeff"))  # older runs lack both: defaults
    checked_feature_coeff(a.get("proximal_feature_coeff"))
    gae_horizon(cfg)
    checked_decay(a.get("policy_ema_decay"))
    adam_betas(a.get("adam_betas", ADAM_BETAS))
    adam_eps(a.get("adam_eps", ADAM_EPS))
    weight_decay(a.get("weight_decay"))
    weight_decay_parts(a.get("weight_decay_parts"))
    log_std_lr(a)
    checked_std_ceiling(
        a.get("std_ceiling"), a.get("std_ceiling_frames", DEFAULT_FRAMES), int(cfg.total_frames)
    )
    advantage_norm_scope(a.get("normalize_advantage"))
    policy_distribution_kwargs(  # runs from before the options: the defaults
        str(a.get("deterministic_action", DEFAULT_DETERMINISTIC_ACTION)),
        str(a.get("action_log_prob", DEFAULT_ACTION_LOG_PROB)),
    )
    if not isinstance(a.get("anneal_step_size", False), bool):
        raise ValueError(f"agent.anneal_step_size must be true or false, got {a.anneal_step_size!r}")
    if cfg.logger.backend not in BACKENDS:
        raise ValueError(f"logger.backend must be one of {list(BACKENDS)}, got {cfg.logger.backend!r}")
    precision = agent_precision(cfg)
    if precision == "bfloat16" and not on_cpu(cfg.device):  # before check_device parses it
        raise ValueError(
            "agent.precision=bfloat16 rounds oneDNN's CPU matrix products; "
            f"with device={cfg.device} use float32"
        )
    if precision == "bfloat16" and not cpu_has_bfloat16():
        print(
            "warning: agent.precision=bfloat16 on a CPU without AVX512-BF16 or AMX: torch emulates its "
            "matrix products, slower than float32; set agent.precision=float32",
            file=sys.stderr,
        )
    check_device(cfg.device)
    positive_int_or_null("torch_threads", cfg.torch_threads)
    interval = cfg.checkpoint.interval_minutes
    if not (is_number(interval) and interval >= 0):
        raise ValueError(f"checkpoint.interval_minutes must be a number >= 0, got {interval!r}")
    if isinstance(cfg.seed, bool) or not isinstance(cfg.seed, int):
        raise ValueError(f"seed must be an integer, got {cfg.seed!r}")
    task_config(cfg.env.task, **OmegaConf.to_container(cfg.env.overrides))  # names a bad env.overrides key
    checked_critic_sizes(cfg.agent.get("critic_encoder_sizes"), bool(cfg.agent.shared_encoder))


def check_device(device) -> None:
    """A one-line error unless ``device`` is ``cpu`` or an available ``cuda[:<index>]``."""
    try:
        kind = torch.device(str(device)).type
    except RuntimeError:
        kind = None
    if kind not in ("cpu", "cuda"):
        raise ValueError(f"device must be cpu or cuda[:<index>], got {device!r}")
    if kind == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device={device} but this machine has no CUDA device; use device=cpu")


def prepare_run(
    cfg: DictConfig, overrides: Sequence[str] = ()
) -> tuple[DictConfig, Path, dict | None, RunLock]:
    """The run's config, directory, (when resuming) checkpoint, and the directory's lock, held.

    A resumed run takes its own saved config (``<run dir>/config.yaml``) with the ``RESUMABLE``
    keys that the command line ``overrides`` change (``run_dir.resume_config``). Another process
    holding the directory is an error before anything in it is touched.
    """
    if cfg.resume:
        run_dir = Path(str(cfg.resume))
        saved = run_dir / "config.yaml"
        if not saved.is_file():
            raise FileNotFoundError(f"resume={run_dir}: no config.yaml there; give a run directory")
        new_cfg = resume_config(OmegaConf.load(saved), cfg, overrides)
        lock = RunLock(writable_dir(run_dir, "resume")).acquire()
        try:
            state = load_checkpoint(run_dir / "checkpoints" / LATEST)
            check_config(new_cfg)
        except BaseException:
            lock.release()
            raise
        return new_cfg, run_dir, state, lock
    if cfg.run_dir:
        run_dir = Path(str(cfg.run_dir))
    else:
        run_dir = Path("runs") / cfg.exp_name / f"{datetime.now():%Y%m%d-%H%M%S}-s{cfg.seed}"
    lock = RunLock(writable_dir(run_dir, "run_dir")).acquire()
    if (run_dir / "checkpoints" / LATEST).exists():
        lock.release()
        raise FileExistsError(f"{run_dir} already holds a run; continue it with resume={run_dir}")
    resolved = OmegaConf.to_container(cfg, resolve=True)
    resolved["run_dir"], resolved["resume"] = str(run_dir), None
    OmegaConf.save(OmegaConf.create(resolved), run_dir / "config.yaml")
    return OmegaConf.create(resolved), run_dir, None, lock


def place_multirun_job(cfg: DictConfig, hydra_cfg: DictConfig) -> bool:
    """Give a multirun job its run directory and its share of the cores (edits ``cfg``).

    The job's directory: its Hydra job directory (``hydra.sweep.dir`` / ``hydra.sweep.subdir``)
    without ``run_dir``; with one ``run_dir=X`` for several jobs, ``X/<job number>`` (our Optuna
    sweeper gives each trial its own ``run_dir``, kept as it is). The same on every start of the
    job: if it already holds a checkpoint, the job continues it, which is how a job requeued after
    the scheduler's time limit (submitit's requeue) resumes. Thread shares:
    ``roto_trl.trainers.threads.job_threads``.

    Returns:
        True when the job continues its directory's checkpoint (``cfg.resume`` set).
    """
    share = job_threads(hydra_cfg.launcher, len(os.sched_getaffinity(0)))
    with open_dict(cfg):
        if share is not None:
            cfg.torch_threads = cfg.torch_threads or share
            if "num_threads" not in cfg.env.overrides:
                cfg.env.overrides.num_threads = share
        if cfg.resume:
            return False
        if not cfg.run_dir:
            job_dir = Path(str(hydra_cfg.runtime.output_dir))
        elif str(hydra_cfg.sweeper.get("_target_", "")).endswith("OptunaSweeper"):
            job_dir = Path(str(cfg.run_dir))
        else:
            job_dir = Path(str(cfg.run_dir)) / str(hydra_cfg.job.num)
        if (job_dir / "checkpoints" / LATEST).exists():
            cfg.resume = str(job_dir)
            return True
        cfg.run_dir = str(job_dir)
        return False


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def rng_state(env) -> dict:
    return {
        "torch": torch.get_rng_state(),
        "numpy": np.random.get_state(),
        "python": random.getstate(),
        "env": env.base_env.rng.bit_generator.state,
    }


def set_rng_state(state: dict, env) -> None:
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
    env.base_env.rng.bit_generator.state = state["env"]


# ---------------------------------------------------------------------------- the run


def train(cfg: DictConfig, overrides: Sequence[str] = ()) -> Path:
    """Run (or resume) PPO training as configured; returns the path of ``summary.json``.

    ``overrides`` are the command line's ``key=value`` arguments: with ``resume=`` only the
    ``RESUMABLE`` ones may be given. The run directory is locked while this runs; a resumed run's
    logs are first cut back to its checkpoint, and a finished one is left unchanged.
    """
    check_config(cfg)
    apply_rollout_floor(cfg)  # the CPU profile's minimum steps per rollout
    apply_precision(cfg)  # auto -> float32 or bfloat16, saved as such
    logging.getLogger("torchrl").setLevel(logging.WARNING)  # its storage notices are not progress
    cfg, run_dir, resumed, lock = prepare_run(cfg, overrides)
    try:
        if resumed is not None:
            reason = finished_reason(cfg, resumed)
            if reason is not None:
                print(
                    f"resume={run_dir}: nothing to do, {reason}; the run is unchanged. Train on with "
                    f"resume={run_dir} total_frames=<more> (or a larger time_limit_minutes)"
                )
                return run_dir / "summary.json"
            OmegaConf.save(cfg, run_dir / "config.yaml")  # an extended budget
            dropped = {kind: n for kind, n in rewind(run_dir, resumed).items() if n}
            if dropped:
                rows = ", ".join(f"{n} of {kind}.csv" for kind, n in dropped.items())
                print(f"resume: dropped the rows logged after the checkpoint ({rows})")
        with StopRequests() as stop:
            return run_training(cfg, run_dir, resumed, stop)
    finally:
        lock.release()


def run_training(cfg: DictConfig, run_dir: Path, resumed: dict | None, stop: StopRequests) -> Path:
    """The run itself, in a prepared and locked ``run_dir``; stops early on ``stop``'s signal."""
    seed_everything(int(cfg.seed))
    torch.set_num_threads(int(cfg.torch_threads) if cfg.torch_threads else len(os.sched_getaffinity(0)))

    # 1. the envs: training worlds and separate evaluation worlds
    env = make_train_env(cfg)
    eval_env = make_eval_env(cfg)
    columns = env.base_env.metric_columns()  # scalar episode metrics, e.g. find_time_3cm

    # 2. the agent, PPO loss, advantage estimator and optimiser
    agent = agent_for_env(cfg, env)
    compile_agent(cfg, agent)  # agent.compile=true only
    loss_fn = make_ppo_loss(cfg, agent)
    terms = make_policy_terms(cfg, agent)  # the mean bound, the proximal feature term: none by default
    advantage = make_advantage(cfg)
    horizon = gae_horizon(cfg)  # None: GAE over the whole rollout
    optimizer = make_optimizer(cfg, agent)
    params = [p for group in optimizer.param_groups for p in group["params"]]
    lr_schedule = make_lr_schedule(cfg, optimizer)  # None: agent.lr throughout (optionally annealed)
    policy_average = make_policy_average(cfg, agent)  # None unless agent.policy_ema_decay > 0
    std_ceiling = make_std_ceiling(cfg, agent, optimizer)  # None unless agent.std_ceiling is set
    aux = make_aux_update(cfg, agent, env)  # the self-supervised objective, or None

    frames, iteration, wall_before = 0, 0, 0.0
    eval_clock = EvalClock()
    best_eval: dict[str, float] | None = None  # the evaluation that best.pt holds
    headline = env.base_env.HEADLINE_METRIC  # ranks evaluations for best.pt (selection_key)
    if resumed is not None:
        agent.load_state_dict(resumed["agent"])
        optimizer.load_state_dict(resumed["optimizer"])
        frames, iteration = int(resumed["frames"]), int(resumed["iteration"])
        wall_before = float(resumed.get("wall_time", 0.0))
        best_eval = resumed.get("best_eval_metrics")
        eval_clock = EvalClock(resumed.get("eval_time", 0.0))
        set_rng_state(resumed["rng"], env)
        if aux is not None:
            aux.load_state_dict(resumed["aux"])
        if policy_average is not None:
            policy_average.load_state_dict(resumed[POLICY_AVERAGE_KEY])
        print(f"resuming {run_dir} at {frames:,} frames (iteration {iteration})")
    if std_ceiling is not None:  # the first rollout's (a resumed run's parameter already under it)
        std_ceiling.set_frames(frames)

    # 3. the collector and the rollout buffer
    collector = make_collector(cfg, env, agent)
    buffer = make_rollout_buffer(cfg)
    keys = minibatch_keys(agent, loss_fn, terms)  # what the buffer keeps of each rollout
    logger = MetricLogger(
        run_dir,
        cfg.logger.backend,
        config=OmegaConf.to_container(cfg),
        name=run_dir.name,
        project=cfg.logger.project,
        resume_frames=None if resumed is None else frames,
    )
    ckpt_dir = run_dir / "checkpoints"
    saved_frames = None if resumed is None else frames  # what latest.pt holds

    def checkpoint(name: str, wall: float) -> None:
        nonlocal saved_frames
        state = {
            "agent": agent.state_dict(),
            "optimizer": optimizer.state_dict(),
            "frames": frames,
            "iteration": iteration,
            "best_eval_metrics": best_eval,
            "wall_time": wall,
            "eval_time": eval_clock.seconds,
            "rng": rng_state(env),
            "config": OmegaConf.to_container(cfg),
        }
        if aux is not None:
            state["aux"] = aux.state_dict()
        if policy_average is not None:  # the controller evaluate.py loads (agent_from_checkpoint)
            state[POLICY_AVERAGE_KEY] = policy_average.state_dict()
        try:
            save_checkpoint(ckpt_dir / name, state)
        except WriteError as err:  # the logs must not run ahead of the last good checkpoint
            logger.truncate(saved_frames or 0)
            raise WriteError(f"{err}; the logs are cut back to the last checkpoint") from None
        if name == LATEST:
            saved_frames = frames

    # 4. the loop
    start = time.perf_counter()
    last_ckpt = start
    ep_return = torch.zeros(cfg.env.num_envs, device=cfg.device)
    final_eval: dict[str, float] | None = None
    every_frames = eval_every_frames(cfg)
    progress = TrainingProgress(int(cfg.total_frames), frames, int(cfg.env.num_envs), bool(cfg.progress))
    progress.watch(agent.policy)  # the bar moves with every collected step
    postfix = progress.postfix
    size = f"{cfg.env.num_envs} worlds, {cfg.total_frames:,} frames"
    print(f"run: {run_dir.resolve()} ({cfg.exp_name}, {size})")
    if resumed is None:  # the untrained policy: where the learning curve starts
        with eval_clock:
            start_eval = evaluate(eval_env, agent, eval_seed(cfg))
        logger.log("eval", {"iteration": 0, **start_eval, "time": eval_clock.last}, 0)
        postfix["eval_return"] = f"{start_eval['return_mean']:.2f}"
    t_collect = time.perf_counter()
    progress.collecting = True
    try:
        for batch in collector:
            progress.collecting = False
            collect_s = time.perf_counter() - t_collect
            iteration += 1
            frames += batch.numel()

            t0 = time.perf_counter()
            store_rollout(batch, agent, advantage, buffer, aux, horizon, keys)
            if lr_schedule is not None:  # the anneal's ramp: the fraction of the budget trained before
                lr_schedule.set_progress((frames - batch.numel()) / cfg.total_frames)
            losses, aux_rows = ppo_update(
                cfg, buffer, agent, loss_fn, optimizer, params, aux, lr_schedule, terms
            )
            if policy_average is not None:
                policy_average.update()
            if std_ceiling is not None:  # the next rollout's ceiling
                losses["std_ceiling"] = std_ceiling.set_frames(frames)
            update_s = time.perf_counter() - t0

            stats = rollout_stats(batch, ep_return, columns, env.base_env.physical_metrics)
            wall = wall_before + time.perf_counter() - start
            stats.update(losses)
            stats.update(
                {
                    "iteration": iteration,
                    "fps": batch.numel() / (collect_s + update_s),
                    "time/collect": collect_s,
                    "time/update": update_s,
                    "wall_time": wall,
                    "time/eval_share": eval_clock.share(wall),  # evaluation's part of the wall time so far
                }
            )
            logger.log("train", stats, frames)
            for row in aux_rows:  # the auxiliary loss of every minibatch, CSV only
                logger.log("aux", {"iteration": iteration, **row}, frames, csv_only=True)

            out_of_time = cfg.time_limit_minutes is not None and wall >= 60 * float(cfg.time_limit_minutes)
            done_training = frames >= cfg.total_frames or out_of_time
            if evaluation_due(frames - batch.numel(), frames, every_frames) or done_training:
                with eval_clock, averaged(policy_average):
                    final_eval = evaluate(eval_env, agent, eval_seed(cfg))
                final_eval["time"] = eval_clock.last
                logger.log("eval", {"iteration": iteration, **final_eval}, frames)
                postfix["eval_return"] = f"{final_eval['return_mean']:.2f}"
                if selection_key(final_eval, headline) > selection_key(best_eval, headline):
                    best_eval = {"frames": frames, **final_eval}
                    checkpoint(LATEST, wall)  # first: best.pt is never newer than latest.pt
                    checkpoint(BEST, wall)
            interval_due = time.perf_counter() - last_ckpt >= 60 * cfg.checkpoint.interval_minutes
            stopping = done_training or stop.signum is not None
            if saved_frames != frames and (stopping or interval_due):
                checkpoint(LATEST, wall)
                last_ckpt = time.perf_counter()
            postfix["fps"] = f"{stats['fps']:,.0f}"
            evals_left = evaluations_left(frames, int(cfg.total_frames), every_frames)
            progress.iteration_done(frames, stats["fps"], evals_left, eval_clock.last)
            if stop.signum is not None and not done_training:
                raise TrainingInterrupted(frames, stop.signum, run_dir)
            if done_training:
                if out_of_time and frames < cfg.total_frames:
                    print(f"time limit of {cfg.time_limit_minutes} min reached at {frames:,} frames")
                break
            t_collect = time.perf_counter()
            progress.collecting = True
    except KeyboardInterrupt as err:  # a second signal: the iteration is abandoned
        if isinstance(err, TrainingInterrupted):
            raise
        logger.truncate(saved_frames or 0)
        raise TrainingInterrupted(saved_frames or 0, stop.signum or signal.SIGINT, run_dir) from None
    finally:
        progress.close()
        collector.shutdown()
        logger.close()
        eval_env.close()

    wall = wall_before + time.perf_counter() - start
    summary = {
        "exp_name": cfg.exp_name,
        "task": cfg.env.task,
        "seed": int(cfg.seed),
        "frames": frames,
        "iterations": iteration,
        "wall_time_s": round(wall, 1),
        "frames_per_s": round(frames / wall, 1) if wall > 0 else None,
        "eval_time_s": round(eval_clock.seconds, 1),
        "eval_share": round(eval_clock.share(wall), 4),
        "best_eval": best_eval,
        "final_eval": final_eval,
        "run_dir": str(run_dir.resolve()),
    }
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    plots = plot_run(run_dir)
    # the physical metrics of the best policy, for the report (also rewrites index.md)
    evaluation = evaluate_run(run_dir, "best", episodes=int(cfg.eval.num_envs))
    share = eval_clock.share(wall)
    print(f"evaluation: {eval_clock.seconds:.0f} s, {share:.1%} of the run's {wall:.0f} s wall time")
    print(f"run directory: {run_dir.resolve()}")
    print(f"plots: {', '.join(str(p.resolve()) for p in plots)}")
    print(f"summary: {(run_dir / 'summary.json').resolve()}")
    print(f"physical metrics of the best checkpoint: {evaluation.resolve()}")
    print(f"report: {(run_dir / 'index.md').resolve()}")
    return run_dir / "summary.json"


OBJECTIVE_EVALS = 3  # a run's objective averages this many last evaluations


def run_objective(run_dir: Path) -> float:
    """A run's objective, what a sweep maximises: the mean ``return_mean`` of the last
    ``OBJECTIVE_EVALS`` evaluations in ``<run_dir>/eval.csv`` (all of them when there are fewer),
    steadier than the final evaluation alone."""
    returns = read_csv(Path(run_dir) / "eval.csv").get("return_mean", [])
    if not returns:
        raise ValueError(f"{run_dir}/eval.csv holds no evaluation")
    last = returns[-OBJECTIVE_EVALS:]
    return sum(last) / len(last)


@hydra.main(config_path=str(resource_dir("conf")), config_name="train", version_base="1.3")
def main(cfg: DictConfig) -> float:
    """Train; return the run's objective (``run_objective``) for a sweep.

    A single run reports in one line: bad input or a run directory in use (exit status 2), a
    NaN/inf stop (3), a failed write such as a full disk (1), SIGINT/SIGTERM (130/143, after
    writing ``latest.pt``). In a multirun the error propagates instead: Hydra's launcher records
    the job as failed and the sweeper goes on with the next trial, where ``sys.exit`` would end
    the whole sweep. A multirun of Hydra's basic sweeper with ``run_dir=`` gives each job its own
    ``<run_dir>/<job number>``.
    """
    hydra_cfg = HydraConfig.get()
    in_sweep = hydra_cfg.mode == RunMode.MULTIRUN
    overrides = list(hydra_cfg.overrides.task)
    if in_sweep and place_multirun_job(cfg, hydra_cfg):
        overrides = []  # a requeued job: the command of its first start, whose config is saved
    try:
        summary = train(cfg, overrides)
    except TrainingInterrupted as err:
        if in_sweep:
            raise
        if err.frames:
            print(
                f"train: stopped at {err.frames:,} frames; continue with: "
                f"python roto_trl/train.py resume={err.run_dir}",
                file=sys.stderr,
            )
        else:
            print(
                f"train: stopped before the first checkpoint; nothing to continue in {err.run_dir}",
                file=sys.stderr,
            )
        sys.exit(128 + err.signum)
    except KeyboardInterrupt:  # before the loop's handlers were installed, or after the loop
        if in_sweep:
            raise
        print("train: interrupted", file=sys.stderr)
        sys.exit(130)
    except NonFiniteError as err:
        if in_sweep:
            raise
        print(f"train: stopped: {err}. The last good checkpoint is intact.", file=sys.stderr)
        sys.exit(EXIT_NON_FINITE)
    except WriteError as err:
        if in_sweep:
            raise
        print(f"train: {err}", file=sys.stderr)
        sys.exit(1)
    except (ValueError, FileNotFoundError, FileExistsError, RunInUse) as err:
        if in_sweep:
            raise
        print(f"train: {err}", file=sys.stderr)
        sys.exit(2)
    return run_objective(summary.parent)


if __name__ == "__main__":
    main()
