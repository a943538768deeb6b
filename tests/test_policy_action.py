"""The policy's deterministic action: the mean of the action the env applies (the clipped sample)
by default, the Gaussian's mean on request; sampling is the Gaussian's, and PPO's
log-probability the Gaussian's density (default) or the applied action's probability."""

import math

import pytest
import torch
from helpers import compose_cfg
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from roto_trl import TASKS, make_env
from roto_trl.modules.agent import Agent
from roto_trl.modules.distributions import (
    ACTION_BOUNDS,
    ClippedActionNormal,
    clipped_normal_log_prob,
    clipped_normal_mean,
    policy_distribution_kwargs,
)
from roto_trl.trainers.builders import agent_for_env, make_ppo_loss

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
    with pytest.raises(ValueError, match=r"deterministic_action must be one of"):
        policy_distribution_kwargs("mode", "gaussian")


def test_clipped_normal_log_prob_by_hand():
    # N(0.5, 1): inside, log phi(-0.5) = -0.125 - log sqrt(2 pi); at or past 1, log(1 - Phi(0.5));
    # at or past -1, log Phi(-1.5); N(2, 0.5) past 1: log Phi(2)
    log_sqrt_2pi = 0.5 * math.log(2 * math.pi)
    loc = torch.tensor([0.5, 0.5, 0.5, 0.5, 2.0])
    scale = torch.tensor([1.0, 1.0, 1.0, 1.0, 0.5])
    value = torch.tensor([0.0, 1.3, 1.0, -2.0, 1.0])
    expected = [
        -0.125 - log_sqrt_2pi,
        math.log(0.30853754),
        math.log(0.30853754),
        math.log(0.0668072),
        math.log(0.97724987),
    ]
    torch.testing.assert_close(
        clipped_normal_log_prob(value, loc, scale), torch.tensor(expected), atol=1e-6, rtol=0
    )
    # far past a bound the tail's log stays finite (log_ndtr), where log(1 - cdf) would be -inf
    far = clipped_normal_log_prob(torch.tensor(1.5), torch.tensor(-9.0), torch.tensor(1.0))
    assert math.isfinite(float(far)) and float(far) < -50


def test_clipped_normal_log_prob_is_a_probability_of_the_applied_action():
    # density over (-1, 1) plus the two masses at the bounds integrate to 1
    loc, scale = torch.tensor(0.7, dtype=torch.float64), torch.tensor(0.8, dtype=torch.float64)
    grid = torch.linspace(-1, 1, 200_001, dtype=torch.float64).clamp(-1 + 1e-12, 1 - 1e-12)  # inside
    inside = torch.trapezoid(clipped_normal_log_prob(grid, loc, scale).exp(), grid)
    masses = clipped_normal_log_prob(torch.tensor([-1.0, 1.0], dtype=torch.float64), loc, scale).exp().sum()
    assert float(inside + masses) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize("deterministic_action", ["applied_mean", "gaussian_mean"])
def test_the_agents_clipped_log_prob(deterministic_action):
    torch.manual_seed(0)
    agent = Agent(("prop",), P, A, deterministic_action=deterministic_action, action_log_prob="clipped")
    with torch.no_grad():
        agent.policy_head.log_std.fill_(0.5)
        out = agent.policy(observations())
    dist = agent.actor_head.get_dist(out)
    # inside the bounds the Gaussian's density; past a bound the same value however far past
    inside = torch.full((6, A), 0.25)
    reference = torch.distributions.Normal(out["loc"], out["scale"])
    torch.testing.assert_close(dist.log_prob(inside), reference.log_prob(inside).sum(-1))
    torch.testing.assert_close(dist.log_prob(torch.full((6, A), 1.5)), dist.log_prob(torch.full((6, A), 7.0)))
    expected = clipped_normal_log_prob(torch.full((6, A), -3.0), out["loc"], out["scale"]).sum(-1)
    torch.testing.assert_close(dist.log_prob(torch.full((6, A), -3.0)), expected)
    torch.testing.assert_close(dist.entropy(), reference.entropy().sum(-1))  # entropy stays the Gaussian's
    # past the upper bound a higher mean raises the log-probability, by less the further the mean
    # is past the bound (the tail mass tends to 1), where the Gaussian's gradient grows with the sample
    loc = torch.tensor([0.0, 1.0, 3.0], requires_grad=True)
    ClippedActionNormal(loc, torch.ones(3), action_log_prob="clipped").log_prob(
        torch.full((3,), 2.0)
    ).backward()
    grad = loc.grad.clone()
    assert bool((grad > 0).all()) and grad[0] > grad[1] > grad[2]
    loc.grad = None
    ClippedActionNormal(loc, torch.ones(3)).log_prob(torch.full((3,), 2.0)).backward()
    torch.testing.assert_close(loc.grad, torch.tensor([2.0, 1.0, -1.0]))  # (a - loc) / scale^2
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        action = agent.policy(observations())["action"]
    expected = (
        out["loc"]
        if deterministic_action == "gaussian_mean"
        else clipped_normal_mean(out["loc"], out["scale"])
    )
    torch.testing.assert_close(action, expected)


def test_ppo_with_the_clipped_log_prob_starts_at_ratio_one():
    # the log-probability stored while acting is the one the loss recomputes: at unchanged
    # weights every ratio is 1 (KL 0, nothing clipped), with many samples past the bounds
    cfg = compose_cfg(["+exp=bounce_ppo", "env.num_envs=2", "agent.action_log_prob=clipped"])
    env = make_env("bounce", 2)
    agent = agent_for_env(cfg, env)
    loss = make_ppo_loss(cfg, agent)
    with torch.no_grad():
        agent.policy_head.log_std.fill_(1.0)
    td = env.reset()
    env.close()
    td = td[:1].expand(64).clone()
    with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
        agent.policy(td)
    assert bool((td["action"].abs() > 1).any())
    expected = clipped_normal_log_prob(td["action"], td["loc"], td["scale"]).sum(-1)
    torch.testing.assert_close(td["action_log_prob"], expected)
    td.set("advantage", torch.randn(64, 1))
    td.set("value_target", torch.randn(64, 1))
    td.set("state_value", torch.randn(64, 1))
    agent.encode(td)
    out = loss(td)
    assert abs(float(out["kl_approx"])) < 1e-5 and float(out["clip_fraction"]) == 0.0
    assert torch.isfinite(out["loss_objective"])


def test_action_log_prob_config():
    assert compose_cfg(["+exp=bounce_ppo"]).agent.action_log_prob == "gaussian"
    with pytest.raises(ValueError, match=r"agent.action_log_prob must be one of \['gaussian', 'clipped'\]"):
        policy_distribution_kwargs("applied_mean", "tanh")
