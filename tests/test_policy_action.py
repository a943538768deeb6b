"""The policy's deterministic action: the mean of the action the env applies (the clipped sample)
by default, the Gaussian's mean on request; sampling and PPO's log-probability are the Gaussian's."""

import math

import pytest
import torch
from helpers import compose_cfg
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from roto_trl import TASKS, make_env
from roto_trl.modules.agent import Agent
from roto_trl.modules.distributions import ACTION_BOUNDS, ClippedActionNormal, clipped_normal_mean
from roto_trl.trainers.builders import agent_for_env

P, A = 5, 4


def test_clipped_normal_mean_by_hand():
    # loc 1, scale 1 in [-1, 1]: a = -2, b = 0, so
    # -Phi(-2) + (1 - 1/2) + (1/2 - Phi(-2)) + (phi(-2) - phi(0)) = 1 - 2 Phi(-2) + phi(2) - phi(0)
    phi0, phi2, cdf_minus2 = 1 / math.sqrt(2 * math.pi), 0.05399097, 0.02275013
    expected = 1 - 2 * cdf_minus2 + phi2 - phi0  # 0.60955
    value = clipped_normal_mean(torch.tensor(1.0), torch.tensor(1.0))
    assert float(value) == pytest.approx(expected, abs=1e-6) and expected == pytest.approx(0.60955, abs=1e-5)
    # symmetric about the middle of the bounds; a vanishing scale gives clip(loc)
    loc = torch.tensor([-0.8, 0.0, 0.3, 1.0, 1.7])
    torch.testing.assert_close(
        clipped_normal_mean(-loc, torch.ones(5)), -clipped_normal_mean(loc, torch.ones(5))
    )
    assert torch.allclose(clipped_normal_mean(loc, torch.full((5,), 1e-6)), loc.clamp(-1, 1))
    # other bounds: N(0, 1) clipped to [0, 2] has mean phi(0) - phi(2) + 2 (1 - Phi(2))
    lo_hi = clipped_normal_mean(torch.tensor(0.0), torch.tensor(1.0), 0.0, 2.0)
    assert float(lo_hi) == pytest.approx(phi0 - phi2 + 2 * cdf_minus2, abs=1e-6)


def test_clipped_normal_mean_is_the_mean_of_clipped_samples():
    g = torch.Generator().manual_seed(0)
    loc = torch.tensor([0.8, -0.4, 0.95, 0.0])
    scale = torch.tensor([1.0, 0.3, 2.0, 0.5])
    samples = (loc + scale * torch.randn(400_000, 4, generator=g)).clamp(*ACTION_BOUNDS)
    torch.testing.assert_close(clipped_normal_mean(loc, scale), samples.mean(0), atol=4e-3, rtol=0)


def test_the_formulas_bounds_are_every_tasks_action_bounds():
    for task in sorted(TASKS):
        env = make_env(task, 2)
        space = env.action_spec.space
        assert float(space.low.min()) == float(space.low.max()) == ACTION_BOUNDS[0], task
        assert float(space.high.min()) == float(space.high.max()) == ACTION_BOUNDS[1], task
        env.close()


def observations(size=6):
    return TensorDict({"prop": torch.randn(size, P, generator=torch.Generator().manual_seed(1))}, [size])


@pytest.mark.parametrize("choice", ["applied_mean", "gaussian_mean"])
def test_the_agents_deterministic_action_and_its_unchanged_gaussian(choice):
    torch.manual_seed(0)
    agent = Agent(("prop",), P, A, deterministic_action=choice)
    with torch.no_grad():
        agent.policy_head.log_std.fill_(0.5)  # std 1.65: far from the Gaussian's mean
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            out = agent.policy(observations())
        expected = clipped_normal_mean(out["loc"], out["scale"]) if choice == "applied_mean" else out["loc"]
        torch.testing.assert_close(out["action"], expected)
        assert not torch.allclose(out["loc"], clipped_normal_mean(out["loc"], out["scale"]))
        # training: the Gaussian's samples and log-probabilities, whichever deterministic action
        dist = agent.actor_head.get_dist(out)
        reference = torch.distributions.Normal(out["loc"], out["scale"])
        action = torch.randn(6, A)
        torch.testing.assert_close(dist.log_prob(action), reference.log_prob(action).sum(-1))
        torch.testing.assert_close(dist.entropy(), reference.entropy().sum(-1))


def test_deterministic_action_config():
    assert compose_cfg(["+exp=bounce_ppo"]).agent.deterministic_action == "applied_mean"
    cfg = compose_cfg(["+exp=bounce_ppo", "env.num_envs=2", "agent.deterministic_action=gaussian_mean"])
    env = make_env("bounce", 2)
    assert agent_for_env(cfg, env).deterministic_action == "gaussian_mean"
    env.close()
    with pytest.raises(
        ValueError, match=r"agent\.deterministic_action must be one of applied_mean, gaussian_mean"
    ):
        compose_cfg(["+exp=bounce_ppo", "agent.deterministic_action=mode"])
    with pytest.raises(ValueError, match=r"deterministic_action must be one of"):
        ClippedActionNormal(torch.zeros(2), torch.ones(2), deterministic_action="mode")
