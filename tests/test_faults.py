"""Faults and bad input: values refused in one line naming the key before any work, runs that
stop or break leave something usable and say what to do, analysis tools refuse what they cannot
count."""

import math

import gymnasium
import pytest
from helpers import TINY, compose_cfg

import roto_trl  # noqa: F401  registers the Gymnasium ids
from roto_trl import make_env
from roto_trl.train import train

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
