"""Evaluation scheduled by frames, its share of the wall time, a progress bar that moves while the
collector steps, and the compiled agent and loss (slow)."""

import pytest
from helpers import TINY, compose_cfg

from roto_trl.train import train
from roto_trl.trainers.builders import (
    agent_for_env,
    compile_agent,
    make_collector,
    make_eval_env,
    make_ppo_loss,
    make_train_env,
    make_update,
)
from roto_trl.trainers.checkpoint import load_checkpoint
from roto_trl.trainers.evaluation import evaluate, selection_key
from roto_trl.trainers.ppo import minibatch_loss
from roto_trl.trainers.progress import TrainingProgress, estimate_line, format_duration, time_to_budget
from roto_trl.trainers.schedule import EvalClock, evaluation_due, evaluations_left


def test_evaluation_falls_on_the_first_iteration_past_each_multiple():
    # 3000 frames per iteration, every 5000: 0->3000 no, 3000->6000 crosses 5000, 6000->9000 no,
    # 9000->12000 crosses 10000
    steps = [(0, 3000), (3000, 6000), (6000, 9000), (9000, 12000)]
    assert [evaluation_due(a, b, 5000) for a, b in steps] == [False, True, False, True]
    assert evaluation_due(0, 5000, 5000) and not evaluation_due(5000, 9999, 5000)
    # the crossings still to come: from 3000 to a 12000 budget, 5000 and 10000
    assert evaluations_left(3000, 12000, 5000) == 2 == sum(evaluation_due(a, b, 5000) for a, b in steps[1:])


def test_best_checkpoint_ranks_the_headline_metric_first_then_the_return():
    # Find: 0.5 within 3 cm beats 0.25 whatever the returns; equal fractions fall to the return
    near, far = {"reached_3cm": 0.5, "return_mean": 80.0}, {"reached_3cm": 0.25, "return_mean": 95.0}
    assert selection_key(near, "reached_3cm") == (0.5, 80.0)
    assert selection_key(near, "reached_3cm") > selection_key(far, "reached_3cm")
    tied = {"reached_3cm": 0.5, "return_mean": 81.0}
    assert selection_key(tied, "reached_3cm") > selection_key(near, "reached_3cm")
    untrained = {"reached_3cm": 0.0, "return_mean": -5.0}
    assert selection_key(None, "reached_3cm") < selection_key(untrained, "reached_3cm")


def test_every_frames_must_be_positive_and_the_old_interval_is_refused():
    assert compose_cfg(["+exp=bounce_ppo", "eval.every_frames=1000"]).eval.every_frames == 1000
    with pytest.raises(ValueError, match=r"eval\.every_frames must be a positive whole number of frames"):
        compose_cfg(["+exp=bounce_ppo", "eval.every_frames=0"])
    with pytest.raises(ValueError, match=r"eval\.interval was replaced by eval\.every_frames"):
        compose_cfg(["+exp=bounce_ppo", "+eval.interval=5"])


def test_eval_clock_sums_evaluations_and_gives_their_share():
    clock = EvalClock(seconds=3.0)
    with clock:
        pass
    assert clock.seconds == pytest.approx(3.0 + clock.last) and clock.last >= 0.0
    assert clock.share(12.0) == pytest.approx(clock.seconds / 12.0) and EvalClock().share(0.0) == 0.0


def test_time_to_budget_and_its_format():
    assert time_to_budget(1_000_000, 2000.0, 4, 5.0) == pytest.approx(520.0)  # 500 s + 4 x 5 s
    assert [format_duration(s) for s in (12.4, 250, 11_100)] == ["12s", "4m 10s", "3h 05m"]


def test_the_estimate_line_does_not_count_untimed_evaluations_as_free():
    timed = estimate_line(1_000_000, 2000.0, 4, 5.0)
    assert timed.endswith("1,000,000 frames to the budget: about 8m 40s with 4 evaluations of 5.0 s")
    # a resumed run prints its line before its first evaluation is timed
    assert estimate_line(1_000_000, 2000.0, 4, 0.0).endswith("about 8m 20s with 4 evaluations not yet timed")
    assert estimate_line(1_000_000, 2000.0, 0, 0.0).endswith("about 8m 20s with no evaluation left")


def test_progress_moves_with_each_collected_step_and_not_during_evaluation():
    cfg = compose_cfg(["+exp=find_ppo", *TINY])  # 8 worlds, 16 steps per rollout
    env, eval_env = make_train_env(cfg), make_eval_env(cfg)
    agent = agent_for_env(cfg, env)
    progress = TrainingProgress(10_000, 0, 8, enabled=True)
    progress.watch(agent.policy)
    seen = []  # the bar's position at each collected step, before the iteration ends

    def record(*_):
        if progress.collecting:
            seen.append(progress.bar.n)

    agent.policy.register_forward_hook(record)
    collector = make_collector(cfg, env, agent)
    progress.collecting = True
    batch = next(iter(collector))
    progress.collecting = False
    assert seen == [8 * (i + 1) for i in range(16)] and batch.numel() == 128
    evaluate(eval_env, agent, seed=1)  # evaluation episodes do not move the bar
    assert progress.bar.n == 128
    progress.iteration_done(128, 1000.0, 2, 1.0)
    assert progress.bar.n == 128
    collector.shutdown()
    eval_env.close()


@pytest.mark.slow
def test_a_compiled_agent_trains_and_its_checkpoint_loads_uncompiled(tmp_path):
    run = tmp_path / "run"
    train(compose_cfg(["+exp=bounce_ppo", *TINY, "agent.compile=true", f"run_dir={run}"]))
    cfg = compose_cfg(["+exp=bounce_ppo", *TINY])
    env = make_train_env(cfg)
    agent_for_env(cfg, env).load_state_dict(load_checkpoint(run)["agent"])  # same parameter names
    env.close()


@pytest.mark.slow
def test_agent_compile_compiles_the_critic_encoder_and_the_ppo_loss_which_match_eager():
    separate_critic = ["agent.shared_encoder=false", "agent.critic_encoder_sizes=[64,32]"]
    cfg = compose_cfg(["+exp=bounce_ppo", *TINY, *separate_critic])
    compiled_cfg = compose_cfg(["+exp=bounce_ppo", *TINY, *separate_critic, "agent.compile=true"])
    env = make_train_env(cfg)
    agent = agent_for_env(cfg, env)
    loss_fn = make_ppo_loss(cfg, agent)
    compiled = agent_for_env(compiled_cfg, env)
    compiled.load_state_dict(agent.state_dict())
    compile_agent(compiled_cfg, compiled)
    compiled_loss = make_ppo_loss(compiled_cfg, compiled)
    networks = (compiled.encoder, compiled.value_encoder, compiled.policy_head, compiled.value_head)
    assert all(m._compiled_call_impl is not None for m in (*networks, compiled_loss))
    assert loss_fn._compiled_call_impl is None
    collector = make_collector(cfg, env, agent)
    update = make_update(cfg, agent, env)
    update.store(next(iter(collector)))
    collector.shutdown()
    minibatch = update.buffer.sample()
    total, losses, _ = minibatch_loss(agent, loss_fn, minibatch.clone())
    compiled_total, compiled_losses, _ = minibatch_loss(compiled, compiled_loss, minibatch.clone())
    assert abs(compiled_total.item() - total.item()) <= 1e-5 * max(1.0, abs(total.item()))
    for key in ("loss_objective", "loss_critic", "loss_entropy", "kl_approx", "clip_fraction"):
        assert abs(compiled_losses[key].item() - losses[key].item()) <= 1e-5, key
    env.close()
