"""PPO on a RoTO task: ``python roto_trl/train.py +exp=<task>_<variant> [key=value ...]``.

    python roto_trl/train.py +exp=find_ppo                         # the paper's Find PPO(prop-tactile)
    python roto_trl/train.py +exp=bounce_ppo_prop +profile=smoke   # a real run in a minute or two
    python roto_trl/train.py resume=runs/find_ppo/20261122-101500-s0   # continue a stopped run

Reads top to bottom: build the envs, the agent and its update (PPO loss, advantage, optimiser,
schedules, rollout buffer, self-supervised objective), the collector and the logger; then the
loop: collect a rollout of every world, update, evaluate every ``eval.every_frames`` frames, log,
checkpoint. Everything of a run lands in its own directory: ``config.yaml``, ``train.csv``,
``eval.csv``, ``checkpoints/{latest,best}.pt``, ``plots/``, ``summary.json``, ``eval.json`` and
``index.md``. ``best.pt`` is the evaluation with the highest headline metric (Find: fraction
within 3 cm; Bounce, Baoding: bounces, rotations per 10 s), the return breaking ties.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import roto_trl  # noqa: F401  first, before torch loads: sets how its OpenMP threads wait (roto_trl/__init__.py)

# isort: split
import hydra
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from roto_trl.analysis.runs import run_objective
from roto_trl.analysis.summary import finish_run, finished_note
from roto_trl.config import check_run_name, checked_config, hydra_overrides, plain, settle_for_machine
from roto_trl.trainers import builders as build
from roto_trl.trainers.checkpoint import BEST, LATEST, RunCheckpoints
from roto_trl.trainers.divergence import DivergenceWatch
from roto_trl.trainers.errors import (
    NonFiniteError,
    TrainingInterrupted,
    end_orphaned_job,
    exit_with_report,
    report_failed_job,
)
from roto_trl.trainers.evaluation import evaluate, selection_key
from roto_trl.trainers.interrupts import StopRequests, orphaned
from roto_trl.trainers.loggers import MetricLogger
from roto_trl.trainers.ppo import rollout_stats
from roto_trl.trainers.progress import TrainingProgress
from roto_trl.trainers.provenance import record_sitting
from roto_trl.trainers.run_dir import place_multirun_job, prepare_run, rewind, save_config
from roto_trl.trainers.schedule import evaluation_due, evaluations_left
from roto_trl.trainers.state import TrainState, rng_state, seed_everything, set_rng_state
from roto_trl.utils.resources import resource_dir


def train(cfg: DictConfig, overrides: Sequence[str] = ()) -> Path:
    """Run (or resume) PPO training as configured; returns the path of ``summary.json``.

    ``overrides`` are the command line's ``key=value`` arguments: with ``resume=`` only the
    ``RESUMABLE`` ones may be given. The run directory is locked while this runs; a resumed run's
    logs are first cut back to its checkpoint, and a finished one is left unchanged.
    """
    check_run_name(overrides)  # +exp=bounce_ppo ssl=fd needs a name of its own
    cfg = checked_config(cfg)
    for note in settle_for_machine(cfg):  # the profile's rollout floor, precision=auto
        print(note)
    logging.getLogger("torchrl").setLevel(logging.WARNING)  # its storage notices are not progress
    cfg, run_dir, resumed, lock = prepare_run(cfg, overrides)
    try:
        if resumed is not None:
            note = finished_note(cfg, run_dir, resumed)  # a finished run: its end files, repaired
            if note is not None:
                print(note)
                return run_dir / "summary.json"
            save_config(cfg, run_dir)  # an extended budget
            rewind(run_dir, resumed)  # the logs and best.pt back to the checkpoint
        with StopRequests() as stop:
            return run_training(cfg, run_dir, resumed, stop, overrides)
    finally:
        lock.release()


def run_training(
    cfg: DictConfig, run_dir: Path, resumed: dict | None, stop: StopRequests, overrides: Sequence[str]
) -> Path:
    """The run itself, in a prepared and locked ``run_dir``; stops early on ``stop``'s signal.
    ``overrides``: the command line's, for the run's record of how it was made."""
    seed_everything(cfg.seed)
    torch.set_num_threads(cfg.torch_threads or len(os.sched_getaffinity(0)))

    # 1. the envs: training worlds and separate evaluation worlds
    env = build.make_train_env(cfg)
    eval_env = build.make_eval_env(cfg)
    headline = env.base_env.HEADLINE_METRIC  # ranks evaluations for best.pt (selection_key)

    # 2. the agent and its update: PPO loss, advantage, optimiser, schedules, buffer, SSL objective
    agent = build.agent_for_env(cfg, env)
    update = build.make_update(cfg, agent, env)
    state = TrainState()
    if resumed is not None:
        update.load_state_dict(resumed)
        state.load_state_dict(resumed)
        set_rng_state(resumed["rng"], env)
        print(f"resuming {run_dir} at {state.frames:,} frames (iteration {state.iteration})")
    record_sitting(run_dir, cfg, state.frames, overrides)  # provenance.json: code, packages, machine, command

    # 3. the collector, the logs and the checkpoints
    collector = build.make_collector(cfg, env, agent)
    logger = MetricLogger(
        run_dir,
        str(cfg.logger.backend),
        config=plain(cfg),
        name=run_dir.name,
        project=cfg.logger.project,
        resume_frames=None if resumed is None else state.frames,
    )
    checkpoints = RunCheckpoints(run_dir, logger, None if resumed is None else state.frames)
    start, eval_before = time.perf_counter(), state.eval_clock.seconds  # this sitting's clocks

    def save(name: str) -> None:
        wall = state.wall_before + time.perf_counter() - start
        snapshot = {
            **update.state_dict(),
            **state.state_dict(wall),
            "rng": rng_state(env),
            "config": plain(cfg),
        }
        checkpoints.save(name, snapshot)

    # 4. the loop
    every_frames, seed = cfg.eval.every_frames, build.eval_seed(cfg)
    divergence = DivergenceWatch.from_config(cfg)
    ep_return = torch.zeros(cfg.env.num_envs, device=cfg.device)
    final_eval: dict[str, float] | None = None
    progress = TrainingProgress(cfg.total_frames, state.frames, cfg.env.num_envs, cfg.progress)
    progress.watch(agent.policy)  # the bar moves with every collected step
    print(
        f"run: {run_dir.resolve()} ({cfg.exp_name}, {cfg.env.num_envs} worlds, {cfg.total_frames:,} frames)"
    )
    if resumed is None:  # the untrained policy: where the learning curve starts
        with state.eval_clock:
            start_eval = evaluate(eval_env, agent, seed)
        logger.log("eval", {"iteration": 0, **start_eval, "time": state.eval_clock.last}, 0)
        progress.postfix["eval_return"] = f"{start_eval['return_mean']:.2f}"
    last_save = t_collect = time.perf_counter()
    progress.collecting = True
    try:
        for batch in collector:
            progress.collecting = False
            collect_s = time.perf_counter() - t_collect
            state.iteration += 1
            state.frames += batch.numel()

            t0 = time.perf_counter()
            losses, aux_rows = update(batch)
            update_s = time.perf_counter() - t0

            stats = rollout_stats(
                batch, ep_return, env.base_env.metric_columns(), env.base_env.physical_metrics
            )
            wall = state.wall_before + time.perf_counter() - start
            stats |= losses | {
                "iteration": state.iteration,
                "fps": batch.numel() / (collect_s + update_s),
                "time/collect": collect_s,
                "time/update": update_s,
                "wall_time": wall,
                "time/eval_share": state.eval_clock.share(wall),  # evaluation's part of the wall time so far
            }
            logger.log("train", stats, state.frames)
            for row in aux_rows if cfg.logger.aux_minibatches else ():  # every auxiliary step, on request
                logger.log("aux", {"iteration": state.iteration, **row}, state.frames, csv_only=True)
            warning = divergence.check(stats, state.frames)  # a DivergedError after stop_after in a row
            if warning:
                progress.bar.write(warning, file=sys.stderr)

            out_of_time = cfg.time_limit_minutes is not None and wall >= 60 * cfg.time_limit_minutes
            done_training = state.frames >= cfg.total_frames or out_of_time
            if evaluation_due(state.frames - batch.numel(), state.frames, every_frames) or done_training:
                with state.eval_clock:
                    final_eval = evaluate(eval_env, agent, seed)
                final_eval["time"] = state.eval_clock.last  # seconds (eval.csv's column time)
                logger.log("eval", {"iteration": state.iteration, **final_eval}, state.frames)
                progress.postfix["eval_return"] = f"{final_eval['return_mean']:.2f}"
                if selection_key(final_eval, headline) > selection_key(state.best_eval, headline):
                    state.best_eval = {"frames": state.frames, **final_eval}
                    save(LATEST)  # first: best.pt is never newer than latest.pt
                    save(BEST)
            interval_due = time.perf_counter() - last_save >= 60 * cfg.checkpoint.interval_minutes
            stopping = done_training or stop.signum is not None
            if checkpoints.saved_frames != state.frames and (stopping or interval_due):
                save(LATEST)
                last_save = time.perf_counter()
            evals_left = evaluations_left(state.frames, cfg.total_frames, every_frames)
            training = time.perf_counter() - start - (state.eval_clock.seconds - eval_before)
            progress.iteration_done(state.frames, stats["fps"], evals_left, state.eval_clock.last, training)
            if stop.signum is not None and not done_training:
                raise TrainingInterrupted(state.frames, stop.signum, run_dir)
            if done_training:
                if out_of_time and state.frames < cfg.total_frames:
                    print(f"time limit of {cfg.time_limit_minutes} min reached at {state.frames:,} frames")
                break
            t_collect = time.perf_counter()
            progress.collecting = True
    except NonFiniteError as err:  # the last checkpoint stands: say which, for the report
        err.run_dir, err.saved_frames = run_dir, checkpoints.saved_frames
        raise
    except KeyboardInterrupt as err:  # a second signal: the iteration is abandoned
        if isinstance(err, TrainingInterrupted):
            raise
        logger.truncate(checkpoints.saved_frames or 0)
        raise TrainingInterrupted(
            checkpoints.saved_frames or 0, stop.signum or signal.SIGINT, run_dir
        ) from None
    finally:
        progress.close()
        collector.shutdown()
        logger.close()
        eval_env.close()
    wall = state.wall_before + time.perf_counter() - start
    return finish_run(cfg, run_dir, state, final_eval, wall, headline)


@hydra.main(config_path=str(resource_dir("conf")), config_name="train", version_base="1.3")
def main(cfg: DictConfig) -> float:
    """Train; return the run's objective for a sweep (``analysis.runs.run_objective`` of the
    sweeper's ``objective``: the task's headline metric unless the sweep names another).

    A single run reports in one line and exits with the status of ``errors.EXIT_STATUS``: bad
    input or a run directory in use (2), a NaN/inf stop (3), a failed write such as a full disk
    (1), SIGINT/SIGTERM (128 + the signal, after writing ``latest.pt``). In a multirun the error
    propagates instead: Hydra's launcher records the job as failed and the sweeper goes on with
    the next trial, where ``sys.exit`` would end the whole sweep; a job whose sweep was killed
    (its launcher is gone) reports in one line and ends its worker process.
    """
    hydra_cfg = HydraConfig.get()
    in_sweep = hydra_cfg.mode == RunMode.MULTIRUN
    overrides = list(hydra_cfg.overrides.task)
    if in_sweep and place_multirun_job(cfg, hydra_cfg):
        overrides = []  # a requeued job: the command of its first start, whose config is saved
    try:
        summary = train(cfg, overrides)
    except BaseException as err:
        if not in_sweep:
            exit_with_report(err)  # one line and the exit status; a bug keeps its traceback
        if not isinstance(err, KeyboardInterrupt):
            report_failed_job(cfg, err)  # error.txt in its run directory, and one line of its own
        if orphaned():
            end_orphaned_job(err)  # the sweep was killed: nobody to raise to
        raise
    if orphaned():  # only a multirun's job watches its parent
        end_orphaned_job(None)
    return run_objective(summary.parent, OmegaConf.select(hydra_cfg, "sweeper.objective", default="headline"))


if __name__ == "__main__":
    sys.argv = [sys.argv[0], *hydra_overrides(sys.argv[1:])]  # +profile= on top of +exp=, in any order
    main()
