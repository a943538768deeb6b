"""The Gymnasium interface: registration, spaces, same-step autoreset, the env checker."""

import os
import subprocess
import sys
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from helpers import OPENMP_DEFAULTS

import roto_trl  # noqa: F401  (registers the ids)
from roto_trl.envs.gymnasium_env import RoToVectorEnv
from roto_trl.envs.registration import ENV_IDS


def test_import_registers_the_ids_and_sets_only_openmp_defaults():
    clean = {k: v for k, v in os.environ.items() if k not in OPENMP_DEFAULTS}
    code = (
        "import os; env = dict(os.environ); import roto_trl, gymnasium; "
        "changed = {k: v for k, v in os.environ.items() if env.get(k) != v}; "
        f"assert changed == {OPENMP_DEFAULTS}, changed; "
        "assert all(i in gymnasium.registry for i in ('RoTO/Find-v0', 'RoTO/Bounce-v0', 'RoTO/Baoding-v0'))"
    )
    subprocess.run([sys.executable, "-c", code], check=True, env=clean)
    # a user's own values win
    code = f"import os, roto_trl; assert [os.environ[k] for k in {list(OPENMP_DEFAULTS)}] == ['ACTIVE', '7']"
    subprocess.run(
        [sys.executable, "-c", code],
        check=True,
        env={**clean, "OMP_WAIT_POLICY": "ACTIVE", "GOMP_SPINCOUNT": "7"},
    )


def test_make_vec_random_loop_autoresets_in_the_same_step():
    n, length = 4, 12
    envs = gymnasium.make_vec("RoTO/Bounce-v0", num_envs=n, episode_steps=length)
    assert isinstance(envs.unwrapped, RoToVectorEnv)
    assert envs.single_action_space.shape == (20,)
    assert envs.single_observation_space["prop"].shape == (4 * 68,)
    assert envs.single_observation_space["tactile"].shape == (4 * 17,)
    obs, info = envs.reset(seed=0)
    assert obs["prop"].shape == (n, 272) and obs["prop"].dtype == np.float32
    assert info["bounces"].shape == (n,) and "reward/air" in info
    envs.action_space.seed(0)
    ended = 0
    for step in range(1, 2 * length + 1):
        obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())
        assert envs.observation_space.contains(obs)
        assert reward.shape == (n,) and terminated.dtype == bool
        done = terminated | truncated
        if step % length == 0 and not terminated.any():
            assert truncated.all()
        for i in np.flatnonzero(done):
            ended += 1
            final = info["final_obs"][i]
            assert final["prop"].shape == (272,)
            # the returned observation is the new episode's first: its history holds one reading
            frames = obs["prop"][i].reshape(4, 68)
            assert np.array_equal(frames, np.broadcast_to(frames[:1], (4, 68)))
            assert not np.array_equal(final["prop"], obs["prop"][i])
            assert info["final_info"][i]["bounces"] >= 0
        for i in np.flatnonzero(~done):
            assert "final_obs" not in info or info["final_obs"][i] is None
    assert ended >= 2 * n
    envs.close()


@pytest.mark.parametrize("env_id", sorted(ENV_IDS.values()))
def test_single_env_passes_the_gymnasium_env_checker(env_id):
    env = gymnasium.make(env_id)
    with warnings.catch_warnings():
        # prop holds joint velocities: unbounded by design
        warnings.filterwarnings("ignore", message=".*Box observation space .*infinity")
        check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_find_metrics_in_info_and_bad_actions():
    envs = gymnasium.make_vec("RoTO/Find-v0", num_envs=2)
    _, info = envs.reset(seed=1)
    assert info["find_time"].shape == (2, 3) and info["object_distance"].shape == (2,)
    with pytest.raises(ValueError, match=r"actions have shape \[2, 8\], expected \[2, 9\]"):
        envs.step(np.zeros((2, 8)))
    envs.close()


def test_a_closed_vector_env_says_so():
    envs = gymnasium.make_vec("RoTO/Bounce-v0", num_envs=2)
    envs.reset(seed=0)
    envs.close()
    with pytest.raises(RuntimeError, match="BounceEnv is closed"):
        envs.step(envs.action_space.sample())


def test_single_env_takes_exact_actions_and_no_step_after_the_end():
    env = gymnasium.make("RoTO/Find-v0", episode_steps=3).unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action has shape \[3, 3\], expected \[9\]"):
        env.step(np.zeros((3, 3)))
    truncated = [env.step(env.action_space.sample())[3] for _ in range(3)]
    assert truncated == [False, False, True]
    with pytest.raises(RuntimeError, match=r"episode has ended .* call reset\(\)"):
        env.step(env.action_space.sample())
    env.reset()
    env.step(env.action_space.sample())
    env.close()
