"""TorchRL contracts of the batched env: specs, shapes, partial resets, determinism, limits."""

import pytest
import torch
from helpers import hold_pose, random_actions
from torchrl.envs import Transform
from torchrl.envs.utils import check_env_specs, step_mdp

from roto_trl import TASKS, make_env

# task -> (prop per reading, tactile per reading, history k, actions): the paper's Table A1
SIZES = {"find": (9 + 9 + 9 + 3 + 4 + 1, 2, 16, 9), "bounce": (68, 17, 4, 20), "baoding": (68, 17, 4, 20)}


@pytest.fixture(params=sorted(TASKS))
def env(request):
    env = make_env(request.param, 3, seed=0)
    env.task = request.param
    yield env
    env.close()


def test_check_env_specs(env):
    check_env_specs(env)


def test_policy_inputs_shapes_and_binary_contacts(env):
    PROP, TACT, K, A = SIZES[env.task]
    assert env.base_env.n_actions == A
    td = env.reset()
    for _ in range(30):
        td = env.step(td.set("action", torch.rand(3, A) * 2 - 1))["next"]
    assert td["prop"].shape == (3, K * PROP) and td["prop"].dtype == torch.float32
    assert td["tactile"].shape == (3, K * TACT) and td["tactile"].dtype == torch.float32
    assert set(td["tactile"].unique().tolist()) <= {0.0, 1.0}
    assert td["contact_force"].shape == (3, TACT) and bool((td["contact_force"] >= 0).all())
    # binarisation at the default threshold is exactly "any force"
    assert torch.equal(td["tactile"][:, -TACT:], (td["contact_force"] > 0).float())
    # the newest reading's last action is the action just applied, clipped
    assert bool((td["prop"][:, -PROP:][:, :A].abs() <= 1).all())
    assert td["state"].dtype == torch.float32 and td.get("reward_terms", None) is not None


def test_base_env_exposes_compiled_model_and_substeps():
    env = make_env("bounce", 2, substeps=4)
    model = env.base_env.mj_model
    assert model.nu == 20
    assert model.opt.timestep == pytest.approx(1 / 240)
    env.close()


def test_partial_reset_leaves_other_envs_untouched_and_restarts_history(env):
    PROP, TACT, K, A = SIZES[env.task]
    td = env.reset()
    actions = random_actions(env, 6)
    for a in actions:
        td = step_mdp(env.step(td.set("action", a)))
    before_state = env.base_env.get_state()
    before = td.clone()
    td["_reset"] = torch.tensor([[False], [True], [False]])
    out = env.reset(td)
    after_state = env.base_env.get_state()
    keep = [0, 2]
    for key in ("prop", "tactile", "state", "contact_force"):
        assert torch.equal(out[key][keep], before[key][keep]), key
    assert torch.equal(after_state["qpos"][keep], before_state["qpos"][keep])
    assert not torch.equal(after_state["qpos"][1], before_state["qpos"][1])
    # the reset env's history holds its first reading k times, with a zero last action
    frames = out["prop"][1].view(K, PROP)
    assert torch.equal(frames, frames[:1].expand(K, -1))
    assert torch.equal(frames[0, :A], torch.zeros(A))
    tact = out["tactile"][1].view(K, TACT)
    assert torch.equal(tact, tact[:1].expand(K, -1))
    # the kept envs still carry their previous last action
    assert not torch.equal(out["prop"][0].view(K, PROP)[-1, :A], torch.zeros(A))


def test_same_seed_and_actions_give_identical_observations():
    runs = []
    for seed in (7, 7, 8):
        env = make_env("baoding", 4, seed=seed)
        td = env.reset()
        out = []
        for a in random_actions(env, 25, seed=1):
            td = env.step(td.set("action", a))["next"]
            out.append(td.select("prop", "tactile", "state", "contact_force").clone())
        runs.append(torch.stack(out))
        env.close()
    assert (runs[0] == runs[1]).all()
    assert not torch.equal(runs[0]["state"], runs[2]["state"])


def test_threads_do_not_change_results():
    states = []
    for threads in (1, 2):
        env = make_env("bounce", 6, seed=3, num_threads=threads)
        td = env.reset()
        for a in random_actions(env, 10):
            td = env.step(td.set("action", a))["next"]
        states.append(env.base_env.get_state()["qpos"])
        env.close()
    assert torch.equal(states[0], states[1])


def test_steps_and_resets_run_torch_on_one_thread_and_restore_the_callers_count():
    """The env's small tensor ops run on one torch thread (roto_trl/envs/one_thread.py); the
    policy and update between steps keep the caller's threads."""
    seen = []

    class CountThreads(Transform):
        def _step(self, tensordict, next_tensordict):
            seen.append(("step", torch.get_num_threads()))
            return next_tensordict

        def _reset(self, tensordict, tensordict_reset):
            seen.append(("reset", torch.get_num_threads()))
            return tensordict_reset

    env = make_env("bounce", 4, seed=0)
    env.append_transform(CountThreads())
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        td = env.reset()
        assert torch.get_num_threads() == 2
        for a in random_actions(env, 3):
            _, td = env.step_and_maybe_reset(td.set("action", a))
            assert torch.get_num_threads() == 2
        env.step(td.set("action", random_actions(env, 1)[0]))
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
        env.close()
    assert seen == [("reset", 1), *[("step", 1)] * 4]


def test_truncation_at_600_steps():
    env = make_env("bounce", 2, seed=0, hand_reset_noise=0.0)
    base = env.base_env
    action = base.default_pose_action().expand(2, -1).clone()
    td = env.reset()
    for step in range(1, 601):
        td = env.step(td.set("action", action))
        nxt = td["next"]
        assert not bool(nxt["terminated"].any()), f"ball fell at step {step} while held"
        assert bool(nxt["truncated"].all()) == (step == 600), step
        td = step_mdp(td)
    assert bool(nxt["done"].all())
    env.close()


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(task="juggle", num_envs=2), "unknown task 'juggle'"),
        (dict(task="bounce", num_envs=0), "num_envs must be a positive integer"),
        (dict(task="bounce", num_envs=2, substep=3), r"unknown override\(s\) \['substep'\]"),
        (dict(task="bounce", num_envs=2, reward_scales={"rotation": 1.0}), "unknown reward term"),
        (dict(task="bounce", num_envs=2, action_ema=0.0), "action_ema must be in"),
        (dict(task="bounce", num_envs=2, substeps=0), "substeps must be >= 1, got 0"),
        (dict(task="find", num_envs=2, tolerances=[0.02, 0.01]), r"must include 0.03 \(3 cm"),
    ],
)
def test_bad_construction_gets_a_clear_error(kwargs, match):
    task, n = kwargs.pop("task"), kwargs.pop("num_envs")
    with pytest.raises(ValueError, match=match):
        make_env(task, n, **kwargs)


def test_wrong_action_shape_is_rejected():
    env = make_env("bounce", 2)
    td = env.reset()
    with pytest.raises(ValueError, match=r"action has shape \[2, 19\] but this env expects \[2, 20\]"):
        env.step(td.set("action", torch.zeros(2, 19)))
    env.close()


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_action_never_reaches_the_simulator(bad):
    env = make_env("baoding", 2)
    td = env.reset()
    state = env.base_env.get_state()
    action = torch.zeros(2, 20)
    action[1, 3] = bad
    with pytest.raises(ValueError, match=r"NaN or inf \(envs \[1\]\)"):
        env.step(td.set("action", action))
    assert (env.base_env.get_state() == state).all()
    env.close()


def test_huge_finite_actions_whose_sum_overflows_are_accepted_and_clipped():
    # the finite check sums the action first; a sum that overflows must fall back to the exact check
    env = make_env("bounce", 2)
    td = env.reset()
    action = torch.full((2, 20), 3e38)
    assert not bool(torch.isfinite(action.sum()))
    env.step(td.set("action", action))
    assert torch.allclose(torch.as_tensor(env.base_env._ctrl[:, 0]), env.base_env.target_high.expand(2, -1))
    env.close()


def test_out_of_range_actions_are_clipped_to_the_ends_of_the_joint_ranges():
    env = make_env("bounce", 1)
    td = hold_pose(env, 1)
    td = env.step(td.set("action", torch.full((1, 20), 50.0)))["next"]
    base = env.base_env
    ctrl = torch.as_tensor(base._ctrl[0, 0])
    assert torch.allclose(ctrl, base.target_high)
    assert bool(torch.isfinite(td["prop"]).all())
    env.close()


@pytest.mark.parametrize(
    ("args", "kwargs", "match"),
    [
        (("bounce", True), {}, "num_envs must be a positive integer, got True"),
        (
            ("bounce", 2),
            {"reward_scales": {"air": "abc"}},
            r"reward_scales\['air'\] must be a finite number, got 'abc'",
        ),
        (("bounce", 10_000_000), {}, r"needs about \d+\.\d GiB .* GiB available; use fewer worlds"),
    ],
)
def test_impossible_envs_are_refused_before_allocating(args, kwargs, match):
    with pytest.raises(ValueError, match=match):
        make_env(*args, **kwargs)


def test_a_closed_env_says_so():
    env = make_env("find", 2)
    td = env.reset()
    env.close()
    for use in (env.reset, lambda: env.step(td.set("action", torch.zeros(2, 9)))):
        with pytest.raises(RuntimeError, match="FindEnv is closed"):
            use()
