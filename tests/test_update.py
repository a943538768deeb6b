"""The PPO update: entropy and log-std conventions, the paper's Eq. 2 with an SSL objective, the
two optimisers, the auxiliary minibatches, the KL-adaptive learning rate, the mean's bound, the
moving average of the policy's weights, the ceiling on the standard deviation and the proximal
feature term."""

import copy
import math

import pytest
import torch
from helpers import TINY, compose_cfg
from omegaconf import OmegaConf
from tensordict import TensorDict

from roto_trl import make_env
from roto_trl.data.memory import AuxMemory
from roto_trl.modules.agent import LATENT_KEY, Agent
from roto_trl.objectives import PolicyMeanBoundLoss, ProximalFeatureLoss, TactileForwardDynamicsLoss
from roto_trl.objectives.functional import excess_square, feature_drift
from roto_trl.train import check_config, train
from roto_trl.trainers.auxiliary import AuxiliaryUpdate
from roto_trl.trainers.builders import (
    agent_for_env,
    apply_rollout_floor,
    gae_horizon,
    make_advantage,
    make_eval_env,
    make_lr_schedule,
    make_mean_bound_loss,
    make_optimizer,
    make_policy_terms,
    make_ppo_loss,
    make_rollout_buffer,
    make_std_ceiling,
    make_train_env,
)
from roto_trl.trainers.loggers import read_csv
from roto_trl.trainers.lr_schedule import kl_adaptive_lr, kl_k3, remaining
from roto_trl.trainers.policy_average import PolicyAverage, policy_parameters, span_note
from roto_trl.trainers.ppo import (
    effective_rank,
    estimate_advantages,
    minibatch_keys,
    minibatch_loss,
    ppo_update,
    rollout_stats,
    saturation,
    store_rollout,
)
from roto_trl.trainers.std_ceiling import std_ceiling

P, T, A = 6, 4, 3
GAUSSIAN_ENTROPY_AT_UNIT_STD = 0.5 * math.log(2 * math.pi * math.e)  # 1.4189..., per dimension


def agent_and_ppo_loss(entropy_coeff=0.0):
    torch.manual_seed(0)
    agent = Agent(("prop", "tactile"), P + T, A)
    cfg = compose_cfg(["+exp=bounce_fd", f"agent.entropy_coeff={entropy_coeff}"])
    return agent, make_ppo_loss(cfg, agent), cfg


def ppo_minibatch(agent, size=16, seed=1):
    """Observations, the policy's own actions and log-probs, and made-up advantages and targets."""
    g = torch.Generator().manual_seed(seed)
    tactile = (torch.rand(size, T, generator=g) > 0.5).float()
    td = TensorDict({"prop": torch.randn(size, P, generator=g), "tactile": tactile}, [size])
    with torch.no_grad():
        agent.policy(td)
    td["advantage"] = torch.randn(size, 1, generator=g)
    td["value_target"] = torch.randn(size, 1, generator=g)
    td["state_value"] = torch.randn(size, 1, generator=g)
    return td.exclude("z")


# ---------------------------------------------------------------------------- entropy and log-std


def test_entropy_bonus_is_c_ent_times_the_mean_entropy_per_action_dimension():
    agent, loss_fn, _ = agent_and_ppo_loss(entropy_coeff=0.1)
    with torch.no_grad():
        agent.policy_head.log_std.fill_(0.5)  # std e^0.5: entropy per dimension 1.4189 + 0.5
    out = loss_fn(agent.encode(ppo_minibatch(agent)))
    per_dimension = GAUSSIAN_ENTROPY_AT_UNIT_STD + 0.5
    assert float(out["loss_entropy"].detach()) == pytest.approx(-0.1 * per_dimension, rel=1e-5)
    assert float(out["entropy"]) == pytest.approx(A * per_dimension, rel=1e-5)  # TorchRL logs the sum
    for bad in ("-0.1", "true", "high"):
        with pytest.raises(ValueError, match=r"agent\.entropy_coeff must be a number >= 0"):
            check_config(compose_cfg(["+exp=find_fd", f"agent.entropy_coeff={bad}"]))


def test_log_std_is_clamped_to_the_authors_range():
    agent = Agent(("prop",), P, A)
    z = torch.zeros(2, agent.encoder.latent_dim)
    with torch.no_grad():
        agent.policy_head.log_std.copy_(torch.tensor([5.0, -30.0, 1.0]))
    _, scale = agent.policy_head(z)
    assert scale[0].tolist() == pytest.approx([math.exp(2.0), math.exp(-20.0), math.exp(1.0)])


# ---------------------------------------------------------------------------- Eq. 2 and the optimisers


def with_tfd(agent, coeff):
    """A TFD objective on ``agent``'s encoder, its memory holding one rollout of 2 worlds x 8 steps."""
    torch.manual_seed(2)
    loss = TactileForwardDynamicsLoss(agent.common, A, T)
    memory = AuxMemory(1, ("prop", "tactile"), action_bounds=(-1.0, 1.0))
    g = torch.Generator().manual_seed(3)
    memory.add(
        TensorDict(
            {
                "prop": torch.randn(2, 8, P, generator=g),
                "tactile": (torch.rand(2, 8, T, generator=g) > 0.5).float(),
                "action": torch.randn(2, 8, A, generator=g),
                "next": TensorDict({"done": torch.zeros(2, 8, 1, dtype=torch.bool)}, [2, 8]),
            },
            [2, 8],
        )
    )
    return AuxiliaryUpdate(loss, memory, lr=1e-3, coeff=coeff, seq_len=3)


def encoder_grad(agent, loss_fn, aux=None, aux_data=None) -> torch.Tensor:
    agent.zero_grad(set_to_none=True)
    if aux is not None:
        aux.zero_grad()
    total, _, _ = minibatch_loss(agent, loss_fn, ppo_minibatch(agent), aux, aux_data)
    total.backward()
    return torch.cat([p.grad.flatten() for p in agent.encoder.parameters()])


def test_eq2_c_aux_scales_only_the_auxiliary_part_of_the_encoders_gradient():
    agent, loss_fn, _ = agent_and_ppo_loss()
    ppo_only = encoder_grad(agent, loss_fn)
    grads = {}
    for coeff in (0.0, 0.5, 1.0):
        aux = with_tfd(agent, coeff)
        data = next(aux.memory.minibatches(1, 3, generator=torch.Generator().manual_seed(0)))
        grads[coeff] = encoder_grad(agent, loss_fn, aux, data)
    assert torch.equal(grads[0.0], ppo_only)  # c_aux = 0: exactly PPO's gradient
    aux_part = grads[0.5] - ppo_only
    assert float(aux_part.abs().max()) > 1e-6  # the auxiliary loss reaches the encoder
    torch.testing.assert_close(grads[1.0] - ppo_only, 2 * aux_part, rtol=1e-4, atol=1e-7)


def test_each_optimiser_holds_only_its_own_parameters_and_one_update_steps_both():
    agent, loss_fn, cfg = agent_and_ppo_loss()
    aux = with_tfd(agent, 1.0)
    optimizer = make_optimizer(cfg, agent)
    ppo_params = {id(p) for g in optimizer.param_groups for p in g["params"]}
    aux_params = {id(p) for g in aux.optimizer.param_groups for p in g["params"]}
    assert ppo_params == {id(p) for p in agent.parameters()}
    assert not ppo_params & aux_params
    own = (aux.loss.forward_model, aux.loss.projector, aux.loss.tactile_decoder)
    assert aux_params == {id(p) for m in own for p in m.parameters()}

    before = {name: p.detach().clone() for name, p in aux.loss.named_parameters()}
    target_before = aux.loss.target_encoder_network_params.clone()
    data = next(aux.epoch(1))
    total, _, stats = minibatch_loss(agent, loss_fn, ppo_minibatch(agent), aux, data)
    optimizer.zero_grad()
    aux.zero_grad()
    total.backward()
    optimizer.step()
    aux.step()
    named = aux.loss.named_parameters()
    changed = {name.split(".")[0] for name, p in named if not torch.equal(p, before[name])}
    assert changed == {"encoder_network_params", "forward_model", "projector", "tactile_decoder"}
    assert stats["aux_loss"] == pytest.approx(stats["loss_dynamics"] + stats["loss_tactile"], rel=1e-5)
    moved = aux.loss.target_encoder_network_params["module", "net", "0", "weight"]
    assert not torch.equal(moved, target_before["module", "net", "0", "weight"])  # the EMA followed


# ---------------------------------------------------------------------------- a separate critic


def test_a_separate_critic_keeps_the_value_loss_out_of_the_policy_encoder():
    torch.manual_seed(0)
    agent = Agent(("prop", "tactile"), P + T, A, shared_encoder=False)
    cfg = compose_cfg(["+exp=bounce_fd", "agent.shared_encoder=false"])
    loss_fn = make_ppo_loss(cfg, agent)
    minibatch = agent.encode(ppo_minibatch(agent))
    agent.zero_grad(set_to_none=True)
    loss_fn(minibatch)["loss_critic"].backward()
    assert all(p.grad is None for p in agent.encoder.parameters())  # the policy's encoder
    assert all(p.grad is not None for p in agent.value_encoder.parameters())
    # the value used for advantages is the critic's own: the policy's z is not read
    minibatch["z"] = torch.full_like(minibatch["z"], float("nan"))
    with torch.no_grad():
        value = agent.normalised_value(minibatch)
        direct = agent.value_head(agent.value_encoder(minibatch["prop"], minibatch["tactile"]))
    assert torch.equal(value, direct)
    # the optimiser steps both encoders; the SSL objectives train the policy's (``common``)
    ids = {id(p) for g in make_optimizer(cfg, agent).param_groups for p in g["params"]}
    assert {id(p) for p in agent.value_encoder.parameters()} <= ids
    assert agent.common.module is agent.encoder


def test_a_smaller_critic_from_the_config_and_the_same_parameter_order():
    cfg = compose_cfg(["+exp=bounce_ppo", "+profile=cpu", "agent.critic_encoder_sizes=[64,32]"])
    env = make_env("bounce", 2)
    small = agent_for_env(cfg, env)
    env.close()
    obs_dim = small.encoder.obs_dim
    layers = [m for m in small.value_encoder.net if isinstance(m, torch.nn.Linear)]
    assert [(m.in_features, m.out_features) for m in layers] == [(obs_dim, 64), (64, 32)]
    assert small.value_head.net[0][0].in_features == 32  # the head reads the critic's latent
    tiny = Agent(("prop", "tactile"), P + T, A, shared_encoder=False, critic_encoder_sizes=[8])
    assert tiny.value(ppo_minibatch(tiny))["state_value"].shape == (16, 1)
    # default sizes: the parameters in the order a checkpoint's Adam state was saved in (policy
    # encoder, policy head, value head, then the critic's encoder), so old runs resume
    default = Agent(("prop", "tactile"), P + T, A, shared_encoder=False)
    names = [n.split(".")[0] for n, _ in default.named_parameters()]
    assert list(dict.fromkeys(names)) == ["encoder", "policy_head", "value_head", "value_encoder"]
    with pytest.raises(ValueError, match="shared_encoder=false"):  # before the run directory is made
        check_config(compose_cfg(["+exp=bounce_ppo", "agent.critic_encoder_sizes=[64]"]))
    for bad in ([], [64, 0], 64, ["a"]):
        with pytest.raises(ValueError, match="list of positive integers"):
            Agent(("prop",), P, A, shared_encoder=False, critic_encoder_sizes=bad)


@pytest.mark.parametrize("exp", ["find_fd", "bounce_ppo", "baoding_fd_mem"])
def test_the_cpu_profile_gives_any_experiment_the_recipe_and_keeps_its_values(exp):
    paper = compose_cfg([f"+exp={exp}"])
    cpu = compose_cfg([f"+exp={exp}", "+profile=cpu"])
    recipe = (cpu.env.num_envs, cpu.agent.shared_encoder, cpu.agent.lr_schedule, cpu.agent.minibatches)
    assert recipe == (256, False, "kl_adaptive", 8)
    assert list(cpu.agent.critic_encoder_sizes) == [256, 128] and paper.agent.critic_encoder_sizes is None
    assert (paper.agent.shared_encoder, paper.agent.lr_schedule) == (True, "fixed")  # the paper's
    for key in ("lr", "rollout_len", "epochs", "entropy_coeff"):
        assert cpu.agent[key] == paper.agent[key]
    assert cpu.ssl == paper.ssl


def test_the_cpu_profile_takes_its_per_task_settings_from_the_task():
    """Bounce's recipe decays the weights (AdamW), Find's and Baoding's do not (plain Adam); Find's
    evaluates on 128 worlds (its 0/1 metric needs them), Bounce's and Baoding's on 32; bounce_ppo
    and find_ppo (the two exps that set it) hold the std under a ceiling falling from 1 to 0.3
    over 0.6-0.9 of the run; find_fd (the exp that sets it) takes Adam's eps 1e-5, the others
    torch's 1e-8; Bounce's and Baoding's matrix products are ``auto`` (bfloat16 where the CPU has
    them), Find's float32."""
    agent = Agent(("prop",), P, A)
    built = {}
    for exp in ("bounce_ppo", "bounce_fd", "find_ppo", "find_fd", "baoding_fd_mem"):
        cfg = compose_cfg([f"+exp={exp}", "+profile=cpu", "total_frames=2000000"])
        check_config(cfg)
        optimizer = make_optimizer(cfg, agent)
        ceiling = make_std_ceiling(cfg, agent, optimizer)
        window = None if ceiling is None else (ceiling.start, ceiling.final, ceiling.begin, ceiling.end)
        decay = optimizer.param_groups[0]["weight_decay"]
        eps = optimizer.param_groups[0]["eps"]
        built[exp] = (type(optimizer).__name__, decay, eps, cfg.eval.num_envs, window, cfg.agent.precision)
    late = (1.0, 0.3, 1_200_000, 1_800_000)
    assert built == {
        "bounce_ppo": ("AdamW", 3.0, 1e-8, 32, late, "auto"),
        "bounce_fd": ("AdamW", 3.0, 1e-8, 32, None, "auto"),
        "find_ppo": ("Adam", 0.0, 1e-8, 128, late, "float32"),
        "find_fd": ("Adam", 0.0, 1e-5, 128, None, "float32"),
        "baoding_fd_mem": ("Adam", 0.0, 1e-8, 32, None, "auto"),
    }
    assert compose_cfg(["+exp=bounce_ppo"]).agent.precision == "float32"  # the paper's run
    kept = compose_cfg(["+exp=bounce_ppo", "+profile=cpu", "agent.precision=float32"])
    assert kept.agent.precision == "float32"  # the command line wins
    assert compose_cfg(["+exp=find_fd"]).agent.adam_eps == 1e-8  # the paper's run: torch's
    paper = compose_cfg(["+exp=bounce_ppo"])
    assert (paper.agent.weight_decay, paper.eval.num_envs) == (0.0, 100)  # the paper's: train.yaml's
    off = compose_cfg(["+exp=bounce_ppo", "+profile=cpu", "agent.weight_decay=0"])
    assert isinstance(make_optimizer(off, agent), torch.optim.Adam)  # the command line wins
    find = compose_cfg(["+exp=find_ppo", "+profile=cpu", "env.cpu_recipe.weight_decay=1.0"])
    assert make_optimizer(find, agent).param_groups[0]["weight_decay"] == 1.0
    assert compose_cfg(["+exp=find_ppo", "+profile=cpu", "eval.num_envs=64"]).eval.num_envs == 64
    assert compose_cfg(["+exp=find_ppo", "+profile=cpu", "agent.std_ceiling=null"]).agent.std_ceiling is None
    find = compose_cfg(["+exp=find_ppo", "+profile=cpu", "+env.overrides.num_threads=1"])
    env = make_eval_env(find)
    assert env.batch_size == torch.Size([128])
    env.close()


def test_the_cpu_profile_lengthens_only_rollouts_under_32_steps(tmp_path, capsys):
    for exp, paper, recipe in (("bounce_ppo", 16, 32), ("find_ppo", 32, 32), ("find_fd", 64, 64)):
        cfg = compose_cfg([f"+exp={exp}", "+profile=cpu"])
        apply_rollout_floor(cfg)
        assert cfg.agent.rollout_len == recipe
        cfg = compose_cfg([f"+exp={exp}"])
        apply_rollout_floor(cfg)  # the paper's exps have no floor
        assert cfg.agent.rollout_len == paper
    assert "agent.rollout_len: 16 -> 32 (agent.min_rollout_len" in capsys.readouterr().out
    kept = compose_cfg(["+exp=bounce_ppo", "+profile=cpu", "agent.min_rollout_len=null"])
    apply_rollout_floor(kept)
    assert kept.agent.rollout_len == 16
    with pytest.raises(ValueError, match=r"agent\.min_rollout_len must be a positive integer or null"):
        apply_rollout_floor(compose_cfg(["+exp=bounce_ppo", "agent.min_rollout_len=0"]))
    run = tmp_path / "run"  # a run trains with, and saves, the lengthened rollout: 8 worlds x 24 steps
    train(compose_cfg(["+exp=bounce_ppo", *TINY, "agent.min_rollout_len=24", f"run_dir={run}"]))
    assert OmegaConf.load(run / "config.yaml").agent.rollout_len == 24
    assert read_csv(run / "train.csv")["frames"] == [192, 384]


def test_value_loss_is_clipped_by_default_and_plain_with_clip_value_null():
    """Prediction v = 1, old value 0, target 2: clipped (0.2) the loss is max((v - 2)^2,
    (0.2 - 2)^2) = 3.24; unclipped (v - 2)^2 = 1; both times critic_coeff 0.1."""
    agent = Agent(("prop",), P, A)
    with torch.no_grad():  # the value head's output is its last layer's bias: v = 1 everywhere
        last = agent.value_head.net[-1]
        last.weight.zero_()
        last.bias.fill_(1.0)
    td = ppo_minibatch(agent)
    td["state_value"] = torch.zeros_like(td["state_value"])
    td["value_target"] = torch.full_like(td["value_target"], 2.0)
    for clip_value, expected in (("0.2", 0.1 * 3.24), ("null", 0.1 * 1.0)):
        cfg = compose_cfg(["+exp=bounce_ppo", f"agent.clip_value={clip_value}"])
        check_config(cfg)
        out = make_ppo_loss(cfg, agent)(agent.encode(td))
        assert float(out["loss_critic"].detach()) == pytest.approx(expected, rel=1e-5)
        assert (out.get("value_clip_fraction", None) is not None) == (clip_value != "null")
    for bad in ("0", "-0.1", "true"):
        with pytest.raises(ValueError, match=r"agent.clip_value must be > 0 or null"):
            check_config(compose_cfg(["+exp=bounce_ppo", f"agent.clip_value={bad}"]))


def test_advantages_are_standardised_per_minibatch_by_default_or_over_the_whole_rollout():
    """One world, two steps, gamma 0.5, lambda 1, values 0, rewards 1 then 3 (the episode ends
    at the second step): GAE 1 + 0.5 x 3 = 2.5 and 3, the value targets the same. Standardised
    over the rollout (mean 2.75, std 0.3536): -0.7071 and 0.7071; the targets stay 2.5 and 3."""

    def rollout():
        zeros = torch.zeros(1, 2, 1)
        done = torch.tensor([[[False], [True]]])
        nxt = {"reward": torch.tensor([[[1.0], [3.0]]]), "done": done, "terminated": done.clone()}
        nxt["state_value"] = zeros.clone()
        return TensorDict({"state_value": zeros.clone(), "next": nxt}, [1, 2])

    agent = Agent(("prop",), P, A)
    expected = {"minibatch": [2.5, 3.0], "batch": [-0.70711, 0.70711], "none": [2.5, 3.0]}
    for scope, advantages in expected.items():
        values = ["agent.gamma=0.5", "agent.lmbda=1.0", f"agent.normalize_advantage={scope}"]
        cfg = compose_cfg(["+exp=bounce_ppo", *values])
        check_config(cfg)
        td = rollout()
        make_advantage(cfg)(td)
        assert td["advantage"].flatten().tolist() == pytest.approx(advantages, abs=1e-4)
        assert td["value_target"].flatten().tolist() == pytest.approx([2.5, 3.0])
        assert make_ppo_loss(cfg, agent).normalize_advantage == (scope == "minibatch")  # in the loss
    legacy = compose_cfg(["+exp=bounce_ppo", "agent.normalize_advantage=true"])  # runs saved before
    assert make_ppo_loss(legacy, agent).normalize_advantage and not make_advantage(legacy).average_gae
    bad = compose_cfg(["+exp=bounce_ppo", "agent.normalize_advantage=rollout"])
    names_the_choices = r"agent\.normalize_advantage must be one of \['minibatch', 'batch', 'none'\]"
    with pytest.raises(ValueError, match=names_the_choices):
        check_config(bad)


def test_gae_horizon_cuts_the_trace_and_bootstraps_from_the_value_there():
    """A rollout of 4 steps without episode ends, by hand from its values V and TD errors d: the
    whole rollout gives A_1 = d_1 + gl d_2 + gl^2 d_3; cut after every 2 steps, A_1 = d_1 and
    A_0 = d_0 + gl d_1 (gl = gamma x lambda), as two rollouts of 2 steps; A_3 = d_3 either way.
    The env's own episode ends are left as they were."""
    cfg = compose_cfg(["+exp=bounce_ppo", "agent.gae_horizon=2"])
    check_config(cfg)
    assert gae_horizon(cfg) == 2 and gae_horizon(compose_cfg(["+exp=bounce_ppo"])) is None
    torch.manual_seed(0)
    agent = Agent(("prop", "tactile"), P + T, A)
    g = torch.Generator().manual_seed(2)

    def observations():
        return {
            "prop": torch.randn(1, 4, P, generator=g),
            "tactile": (torch.rand(1, 4, T, generator=g) > 0.5).float(),
        }

    no_end = torch.zeros(1, 4, 1, dtype=torch.bool)
    nxt = {
        **observations(),
        "reward": torch.randn(1, 4, 1, generator=g),
        "done": no_end,
        "terminated": no_end,
    }
    batch = TensorDict({**observations(), "next": nxt}, [1, 4])
    with torch.no_grad():
        agent.policy(batch)
        value = agent.value_norm.denormalize(agent.normalised_value(batch)).flatten()
        last = agent.raw_value(batch["next"][:, -1]).flatten()
    gl = 0.99 * 0.95
    d = (batch["next", "reward"].flatten() + 0.99 * torch.cat([value[1:], last]) - value).tolist()
    advantages = {}
    for horizon in (None, 2):
        td = batch.clone()
        estimate_advantages(td, copy.deepcopy(agent), make_advantage(cfg), horizon)  # the norm moves
        advantages[horizon] = td["advantage"].flatten().tolist()
        assert not td["next", "done"].any()
    assert advantages[None][1] == pytest.approx(d[1] + gl * d[2] + gl**2 * d[3], abs=1e-5)
    assert advantages[2][1] == pytest.approx(d[1], abs=1e-5)
    assert advantages[2][0] == pytest.approx(d[0] + gl * d[1], abs=1e-5)
    assert advantages[2][3] == pytest.approx(advantages[None][3]) == pytest.approx(d[3], abs=1e-5)
    with pytest.raises(ValueError, match=r"agent\.gae_horizon must be a positive integer or null"):
        check_config(compose_cfg(["+exp=bounce_ppo", "agent.gae_horizon=0"]))


def test_the_shared_agent_reads_the_policys_latent_for_its_value():
    torch.manual_seed(0)
    agent = Agent(("prop",), P, A)
    td = ppo_minibatch(agent)
    agent.encode(td)
    with torch.no_grad():
        assert torch.equal(agent.normalised_value(td), agent.value_head(td["z"]))
    assert not hasattr(agent, "value_encoder")


# ---------------------------------------------------------------------------- the KL-adaptive rate


def test_kl_k3_by_hand():
    # ratios 0.5 and 2: mean r = 1.25, mean(-log r) = 0; (0.5 - 1 + ln 2 + 2 - 1 - ln 2) / 2 = 0.25
    assert kl_k3(0.0, 1.25) == pytest.approx(0.25)


def test_kl_adaptive_rule_by_hand():
    # target 0.008: above 0.016 divide by 1.5, below 0.004 multiply by 1.5, between keep
    assert kl_adaptive_lr(3e-4, 0.02, 0.008) == pytest.approx(2e-4)
    assert kl_adaptive_lr(3e-4, 0.001, 0.008) == pytest.approx(4.5e-4)
    assert kl_adaptive_lr(3e-4, 0.016, 0.008) == 3e-4  # the bounds themselves keep the rate
    assert kl_adaptive_lr(3e-4, 0.004, 0.008) == 3e-4
    assert kl_adaptive_lr(1.2e-6, 1.0, 0.008) == 1e-6  # clamped to [1e-6, 1e-2]
    assert kl_adaptive_lr(8e-3, 0.0, 0.008) == 1e-2


def test_lr_schedule_config():
    agent = Agent(("prop",), P, A)
    optimizer = torch.optim.Adam(agent.parameters(), lr=3e-4)
    assert make_lr_schedule(compose_cfg(["+exp=bounce_ppo"]), optimizer) is None  # fixed by default
    cfg = compose_cfg(["+exp=bounce_ppo", "agent.lr_schedule=kl_adaptive"])
    schedule = make_lr_schedule(cfg, optimizer)
    assert schedule.step(0.05) == pytest.approx(2e-4)  # KL 0.05 > 2 x 0.008
    assert optimizer.param_groups[0]["lr"] == pytest.approx(2e-4)
    with pytest.raises(ValueError, match=r"agent\.lr_schedule must be one of"):
        make_lr_schedule(compose_cfg(["+exp=bounce_ppo", "agent.lr_schedule=cosine"]), optimizer)


def test_the_step_size_anneals_linearly_to_zero_over_the_budget():
    """Fixed rate 3e-4: half-way 1.5e-4, at the end 0. KL rule, target 0.008 annealed half-way to
    0.004: a KL of 0.01 (between 0.004 and 0.016, kept without the anneal) is now above twice the
    target, so the rate is divided by 1.5."""
    assert remaining(3e-4, 0.5) == pytest.approx(1.5e-4) and remaining(3e-4, 1.2) == 0.0
    agent = Agent(("prop",), P, A)
    optimizer = torch.optim.Adam(agent.parameters(), lr=3e-4)
    fixed = make_lr_schedule(
        compose_cfg(["+exp=bounce_ppo", "agent.lr=3e-4", "agent.anneal_step_size=true"]), optimizer
    )
    fixed.set_progress(0.5)
    assert optimizer.param_groups[0]["lr"] == pytest.approx(1.5e-4)
    assert fixed.step(1.0) == pytest.approx(1.5e-4)  # the KL does not move the annealed fixed rate
    fixed.set_progress(1.0)
    assert optimizer.param_groups[0]["lr"] == 0.0
    for anneal, expected in ((False, 3e-4), (True, 2e-4)):
        optimizer = torch.optim.Adam(agent.parameters(), lr=3e-4)
        values = ["agent.lr_schedule=kl_adaptive", f"agent.anneal_step_size={anneal}"]
        schedule = make_lr_schedule(compose_cfg(["+exp=bounce_ppo", *values]), optimizer)
        schedule.set_progress(0.5)
        assert schedule.step(0.01) == pytest.approx(expected)
    with pytest.raises(ValueError, match=r"agent\.anneal_step_size must be true or false"):
        check_config(compose_cfg(["+exp=bounce_ppo", "agent.anneal_step_size=linear"]))


def test_the_log_std_can_keep_the_fixed_rate_while_the_kl_rule_moves_the_rest():
    agent = Agent(("prop",), P, A)
    cfg = compose_cfg(["+exp=bounce_ppo", "agent.lr_schedule=kl_adaptive", "agent.log_std_fixed_lr=true"])
    optimizer = make_optimizer(cfg, agent)
    networks, log_std = optimizer.param_groups
    assert log_std["params"] == [agent.policy_head.log_std]  # each parameter in exactly one group
    assert {id(p) for p in networks["params"]} == {id(p) for p in agent.parameters()} - {
        id(agent.policy_head.log_std)
    }
    make_lr_schedule(cfg, optimizer).step(0.05)  # KL above 2 x 0.008: lr / 1.5 for the networks only
    assert networks["lr"] == pytest.approx(cfg.agent.lr / 1.5) and log_std["lr"] == cfg.agent.lr
    # and it survives a checkpoint: the group's flag and rate come back with the optimiser's state
    again = make_optimizer(cfg, Agent(("prop",), P, A))
    again.load_state_dict(optimizer.state_dict())
    assert [g["lr"] for g in again.param_groups] == [networks["lr"], log_std["lr"]]
    assert again.param_groups[1]["kl_adaptive"] is False
    # off by default: one group
    assert len(make_optimizer(compose_cfg(["+exp=bounce_ppo"]), agent).param_groups) == 1


def test_the_log_std_can_have_a_rate_of_its_own_outside_the_kl_rule_and_annealed_from_it():
    agent = Agent(("prop",), P, A)
    cfg = compose_cfg(["+exp=bounce_ppo", "agent.lr_schedule=kl_adaptive", "agent.log_std_lr=1e-3"])
    optimizer = make_optimizer(cfg, agent)
    networks, log_std = optimizer.param_groups
    assert log_std["params"] == [agent.policy_head.log_std] and log_std["kl_adaptive"] is False
    assert (networks["lr"], log_std["lr"]) == (cfg.agent.lr, 1e-3)
    make_lr_schedule(cfg, optimizer).step(0.001)  # KL under 0.008 / 2: x 1.5 for the networks only
    assert (networks["lr"], log_std["lr"]) == (pytest.approx(cfg.agent.lr * 1.5), 1e-3)
    # the annealed fixed rate takes each group from its own start: half way, half of each
    fixed = ["+exp=bounce_ppo", "agent.log_std_lr=1e-3", "agent.anneal_step_size=true", "agent.lr=1e-4"]
    optimizer = make_optimizer(compose_cfg(fixed), agent)
    make_lr_schedule(compose_cfg(fixed), optimizer).set_progress(0.5)
    assert [g["lr"] for g in optimizer.param_groups] == [pytest.approx(5e-5), pytest.approx(5e-4)]
    for bad in ("0", "-1e-3", "fast"):
        with pytest.raises(ValueError, match=r"agent\.log_std_lr must be a number > 0 or null"):
            check_config(compose_cfg(["+exp=bounce_ppo", f"agent.log_std_lr={bad}"]))


def test_adam_betas_from_the_config_torchs_by_default():
    agent = Agent(("prop",), P, A)
    assert make_optimizer(compose_cfg(["+exp=bounce_ppo"]), agent).param_groups[0]["betas"] == (0.9, 0.999)
    equal = make_optimizer(compose_cfg(["+exp=bounce_ppo", "agent.adam_betas=[0.99,0.99]"]), agent)
    assert equal.param_groups[0]["betas"] == (0.99, 0.99)
    for bad in ("[0.9]", "[0.9,1.0]", "0.9", "[a,b]"):
        with pytest.raises(
            ValueError, match=r"agent\.adam_betas must be \[beta1, beta2\] with each in \[0, 1\)"
        ):
            check_config(compose_cfg(["+exp=bounce_ppo", f"agent.adam_betas={bad}"]))


def test_adam_eps_from_the_config_damps_the_step_of_a_quiet_parameter():
    agent = Agent(("prop",), P, A)
    assert make_optimizer(compose_cfg(["+exp=bounce_ppo"]), agent).param_groups[0]["eps"] == 1e-8
    for decay in ("0.0", "1.0"):  # Adam and AdamW both take it
        cfg = compose_cfg(["+exp=bounce_ppo", "agent.adam_eps=1e-5", f"agent.weight_decay={decay}"])
        assert {g["eps"] for g in make_optimizer(cfg, agent).param_groups} == {1e-5}
    # Adam's first step is lr * g / (|g| + eps): a gradient of 1e-5 moves the log-std by
    # 1e-3 * 1e-5 / (1e-5 + 1e-8) = 1e-3 / 1.001 with torch's eps, by 1e-3 / 2 with eps 1e-5
    for eps, step in ((1e-8, 1e-3 / 1.001), (1e-5, 0.5e-3)):
        cfg = compose_cfg(
            ["+exp=bounce_ppo", "agent.lr=1e-3", f"agent.adam_eps={eps}", "agent.fused_adam=false"]
        )
        optimizer = make_optimizer(cfg, agent)
        log_std = agent.policy_head.log_std
        before = log_std.detach().clone()
        optimizer.zero_grad()
        log_std.grad = torch.full_like(log_std, 1e-5)
        optimizer.step()
        torch.testing.assert_close(before - log_std.detach(), torch.full_like(before, step))
    for bad in ("0", "-1e-5", "small"):
        with pytest.raises(ValueError, match=r"agent\.adam_eps must be a number > 0, e\.g\. 1e-5"):
            check_config(compose_cfg(["+exp=bounce_ppo", f"agent.adam_eps={bad}"]))


def test_weight_decay_shrinks_the_weight_matrices_by_lr_times_decay_and_nothing_else():
    agent = Agent(("prop",), P, A)
    assert isinstance(make_optimizer(compose_cfg(["+exp=bounce_ppo"]), agent), torch.optim.Adam)  # off
    cfg = compose_cfg(["+exp=bounce_ppo", "agent.weight_decay=0.5", "agent.lr=0.01"])
    optimizer = make_optimizer(cfg, agent)
    assert isinstance(optimizer, torch.optim.AdamW)
    named = dict(agent.named_parameters())
    before = {name: p.detach().clone() for name, p in named.items()}
    for p in agent.parameters():  # a zero gradient: Adam's own step is 0, only the decay moves
        p.grad = torch.zeros_like(p)
    optimizer.step()
    for name, p in named.items():
        # a matrix: w <- w - lr * decay * w = 0.995 w; biases, LayerNorm and the log-std stay
        expected = before[name] * (1 - 0.01 * 0.5) if p.dim() >= 2 else before[name]
        torch.testing.assert_close(p.detach(), expected, msg=name)
    assert sum(len(g["params"]) for g in optimizer.param_groups) == len(named)  # each once
    fixed = make_optimizer(
        compose_cfg(["+exp=bounce_ppo", "agent.weight_decay=0.5", "agent.log_std_fixed_lr=true"]), agent
    )
    assert [g["weight_decay"] for g in fixed.param_groups] == [0.5, 0.0, 0.0]
    assert fixed.param_groups[2]["params"] == [agent.policy_head.log_std]
    assert fixed.param_groups[2]["kl_adaptive"] is False
    for bad in ("-0.1", "a"):
        with pytest.raises(ValueError, match=r"agent\.weight_decay must be a number >= 0"):
            check_config(compose_cfg(["+exp=bounce_ppo", f"agent.weight_decay={bad}"]))


def test_weight_decay_parts_limit_the_decay_to_the_named_parts_of_the_agent():
    agent = Agent(("prop",), P, A, shared_encoder=False, critic_encoder_sizes=[8])
    only_head = ["agent.weight_decay=0.5", "agent.lr=0.01", "agent.weight_decay_parts=[policy_head]"]
    optimizer = make_optimizer(compose_cfg(["+exp=bounce_ppo", *only_head]), agent)
    named = dict(agent.named_parameters())
    before = {name: p.detach().clone() for name, p in named.items()}
    for p in agent.parameters():  # a zero gradient: only the decay moves
        p.grad = torch.zeros_like(p)
    optimizer.step()
    shrunk = [name for name, p in named.items() if not torch.equal(p.detach(), before[name])]
    assert shrunk and all(name.startswith("policy_head.") for name in shrunk)
    for name in shrunk:  # every policy-head matrix by lr * decay, nothing else anywhere
        torch.testing.assert_close(named[name].detach(), before[name] * (1 - 0.01 * 0.5), msg=name)
    assert len(shrunk) == sum(p.dim() >= 2 for p in agent.policy_head.parameters())
    assert sum(len(g["params"]) for g in optimizer.param_groups) == len(named)  # each once
    two = make_optimizer(
        compose_cfg(
            ["+exp=bounce_ppo", "agent.weight_decay=0.5", "agent.weight_decay_parts=[encoder,value_encoder]"]
        ),
        agent,
    )
    matrices = [p for part in (agent.encoder, agent.value_encoder) for p in part.parameters() if p.dim() >= 2]
    assert {id(p) for p in two.param_groups[0]["params"]} == {id(p) for p in matrices}
    for bad in ("[]", "[critic]", "policy_head", "[policy_head,7]"):
        with pytest.raises(
            ValueError, match=r"agent\.weight_decay_parts must be a non-empty list of encoder"
        ):
            check_config(compose_cfg(["+exp=bounce_ppo", f"agent.weight_decay_parts={bad}"]))


def test_the_forward_model_learns_from_the_action_the_env_applied():
    from roto_trl.trainers.builders import agent_for_env, make_aux_update, make_collector, make_train_env

    cfg = compose_cfg(["+exp=bounce_fd", "env.num_envs=2", "agent.rollout_len=3"])
    env = make_train_env(cfg)
    agent = agent_for_env(cfg, env)
    with torch.no_grad():
        agent.policy_head.log_std.fill_(1.0)  # std e: most samples fall outside [-1, 1]
    collector = make_collector(cfg, env, agent)  # what training collects
    rollout = next(iter(collector))
    collector.shutdown()
    aux = make_aux_update(cfg, agent, env)
    aux.memory.add(rollout)
    sampled = rollout["action"]
    assert bool((sampled.abs() > 1).any())
    assert torch.equal(aux.memory.stored()["action"][0], sampled.clamp(-1.0, 1.0))  # the env's clip
    # the auxiliary optimiser follows agent.fused_adam, as the PPO optimiser does
    assert aux.optimizer.defaults["fused"] and make_optimizer(cfg, agent).defaults["fused"]


def test_the_initial_log_std_is_configurable_and_the_papers_is_zero():
    assert compose_cfg(["+exp=bounce_ppo"]).agent.init_log_std == 0.0
    agent = Agent(("prop",), P, A, init_log_std=-1.0)
    _, scale = agent.policy_head(torch.zeros(3, agent.encoder.latent_dim))
    torch.testing.assert_close(scale, torch.full((3, A), math.exp(-1.0)))


# ---------------------------------------------------------------------------- the policy mean's bound


def agent_with_preactivation(u):
    """An agent whose policy mean's pre-tanh output is ``u`` ``[A]`` in every state."""
    agent = Agent(("prop", "tactile"), P + T, A)
    with torch.no_grad():
        agent.policy_head.mean.weight.zero_()
        agent.policy_head.mean.bias.copy_(torch.tensor(u))
    return agent


def test_excess_square_by_hand():
    # relu(|x| - 2) = [1, 0, 0, 0.5]; squares [1, 0, 0, 0.25]; mean 1.25 / 4
    assert float(excess_square(torch.tensor([-3.0, -1.0, 0.5, 2.5]), 2.0)) == pytest.approx(0.3125)


def test_mean_bound_loss_by_hand_and_only_past_the_bound():
    agent = agent_with_preactivation([3.0, -0.5, 1.0])
    td = agent.encode(ppo_minibatch(agent))
    out = PolicyMeanBoundLoss(agent.policy_head, bound=2.0, coeff=0.5)(td)
    # 0.5 * mean([1, 0, 0]); |tanh u| = 0.995, 0.46, 0.76: one of three saturated; mean |u| 1.5
    assert float(out["loss_mean_bound"].detach()) == pytest.approx(0.5 / 3)
    assert float(out["mean_saturation"]) == pytest.approx(1 / 3)
    assert float(out["mean_preactivation_abs"]) == pytest.approx(1.5)
    out["loss_mean_bound"].backward()
    # d/du_0 of 0.5 * sum_rows (u_0 - 2)^2 / (rows * 3) = 0.5 * 2 * 1 / 3, the same for the bias
    assert agent.policy_head.mean.bias.grad.tolist() == pytest.approx([1 / 3, 0.0, 0.0])
    off = PolicyMeanBoundLoss(agent.policy_head, coeff=0.0)(td)
    assert float(off["loss_mean_bound"]) == 0.0 and not off["loss_mean_bound"].requires_grad
    assert float(off["mean_saturation"]) == pytest.approx(1 / 3)  # the diagnostic either way
    renamed = PolicyMeanBoundLoss(agent.policy_head, coeff=0.5)
    renamed.set_keys(latent="latent")
    moved = td.clone()
    moved.rename_key_("z", "latent")
    assert float(renamed(moved)["loss_mean_bound"].detach()) == pytest.approx(0.5 / 3)


def test_the_mean_bound_joins_the_minibatch_loss_only_with_a_weight():
    agent = agent_with_preactivation([3.0, -0.5, 1.0])
    cfg = compose_cfg(["+exp=bounce_ppo"])
    loss_fn, batch = make_ppo_loss(cfg, agent), ppo_minibatch(agent)
    plain = minibatch_loss(agent, loss_fn, batch.clone())[0].detach()
    assert make_mean_bound_loss(cfg, agent) is None  # agent.mean_bound_coeff 0: no extra work
    weighted = make_mean_bound_loss(compose_cfg(["+exp=bounce_ppo", "agent.mean_bound_coeff=0.5"]), agent)
    total, losses, _ = minibatch_loss(agent, loss_fn, batch.clone(), terms=(weighted,))
    assert float(total.detach()) == pytest.approx(float(plain) + 0.5 / 3, rel=1e-5)
    assert float(losses["mean_saturation"]) == pytest.approx(1 / 3)
    # every run logs the saturation of the loc the policy wrote while acting: 2 of these 4 > 0.9
    assert saturation(torch.tensor([[0.95, -0.2], [-0.91, 0.9]])) == pytest.approx(0.5)
    bad_values = (("agent.mean_bound=0", "mean_bound must be"), ("agent.mean_bound_coeff=-1", "coeff must"))
    for bad, match in bad_values:
        with pytest.raises(ValueError, match=match):
            check_config(compose_cfg(["+exp=bounce_ppo", bad]))


# ---------------------------------------------------------------------------- the policy's average


def test_policy_average_by_hand_and_swapped_in_only_inside_the_block():
    torch.manual_seed(0)
    agent = Agent(("prop", "tactile"), P + T, A, shared_encoder=False, critic_encoder_sizes=(8,))
    names = set(policy_parameters(agent))
    assert names and all(n.startswith(("encoder.", "policy_head.")) for n in names)
    assert "policy_head.log_std" in names and not any(n.startswith("value") for n in names)
    with torch.no_grad():
        for p in agent.parameters():
            p.fill_(0.0)
    average = PolicyAverage(agent, 0.5)  # starts at the current weights: 0
    critic_before = agent.value_encoder.net[0].weight.clone()
    for weight in (2.0, 4.0):
        with torch.no_grad():
            for p in policy_parameters(agent).values():
                p.fill_(weight)
        average.update()
    # 0.5 * (0.5 * 0 + 0.5 * 2) + 0.5 * 4 = 2.5
    assert all(torch.all(t == 2.5) for t in average.state_dict().values())
    with average.swapped_in():
        assert torch.all(agent.policy_head.log_std == 2.5) and torch.all(agent.encoder.net[0].weight == 2.5)
    assert torch.all(agent.policy_head.log_std == 4.0)  # the trained weights are back
    assert torch.equal(agent.value_encoder.net[0].weight, critic_before)  # never averaged
    restored = PolicyAverage(agent, 0.5)
    restored.load_state_dict(average.state_dict())
    assert all(torch.all(t == 2.5) for t in restored.state_dict().values())
    with pytest.raises(ValueError, match="does not fit this agent"):
        restored.load_state_dict({"encoder.other": torch.zeros(1)})
    for bad in (1.0, -0.1, "'0.9'"):
        with pytest.raises(ValueError, match="policy_ema_decay must be a number in"):
            check_config(compose_cfg(["+exp=bounce_ppo", f"agent.policy_ema_decay={bad}"]))


def test_span_note_flags_an_average_longer_than_half_the_run():
    # 0.998 spans 1 / 0.002 = 500 iterations; a 2 M-frame Find run has 2e6 // 16384 = 122
    note = span_note(0.998, 122)
    assert "about 500 iterations" in note and "has 122" in note
    assert "agent.policy_ema_decay=0.92" in note  # 1 - 10 / 122 = 0.918
    assert span_note(0.9, 122) is None  # 10 iterations fit
    assert span_note(0.9, 20) is None  # 10 iterations, exactly half the run
    assert "needs no average: agent.policy_ema_decay=0" in span_note(0.9, 19)  # too short for 1 - 10 / 19
    assert span_note(0.0, 1) is None  # off


# ---------------------------------------------------------------------------- the std ceiling


def test_std_ceiling_by_hand():
    # held at 1 up to 0.5 M, log-linear to 0.25 at 1.5 M: log 0.25 = -1.386, halfway -0.693 = log 0.5
    assert std_ceiling(0, 1.0, 0.25, 500_000, 1_500_000) == pytest.approx(1.0)
    assert std_ceiling(500_000, 1.0, 0.25, 500_000, 1_500_000) == pytest.approx(1.0)
    assert std_ceiling(1_000_000, 1.0, 0.25, 500_000, 1_500_000) == pytest.approx(0.5)
    assert std_ceiling(750_000, 1.0, 0.25, 500_000, 1_500_000) == pytest.approx(0.25**0.25)  # 0.7071
    assert std_ceiling(1_500_000, 1.0, 0.25, 500_000, 1_500_000) == pytest.approx(0.25)
    assert std_ceiling(3_000_000, 1.0, 0.25, 500_000, 1_500_000) == pytest.approx(0.25)  # stays after
    assert std_ceiling(100, 2.0, 0.5, 0, 200) == pytest.approx(1.0)  # exp(init_log_std) may be any start


def test_the_std_ceiling_holds_the_log_std_under_it_after_every_step_and_below_it_learns():
    torch.manual_seed(0)
    agent = Agent(("prop",), P, A)
    frames = ["agent.std_ceiling=0.25", "agent.std_ceiling_frames=[100,200]"]
    cfg = compose_cfg(["+exp=bounce_ppo", *frames])
    optimizer = make_optimizer(cfg, agent)
    ceiling = make_std_ceiling(cfg, agent, optimizer)
    log_std = agent.policy_head.log_std
    assert ceiling.set_frames(100) == pytest.approx(1.0) and torch.all(log_std == 0.0)  # not yet falling
    assert ceiling.set_frames(150) == pytest.approx(0.5)
    assert torch.allclose(log_std, torch.full((A,), math.log(0.5)))  # projected at once
    with torch.no_grad():
        log_std[0] = -2.0  # under the ceiling: learns freely
    for _ in range(3):  # gradients that push every log-std up
        optimizer.zero_grad()
        (-agent.policy_head.log_std.sum()).backward()
        optimizer.step()
    assert torch.allclose(log_std[1:], torch.full((A - 1,), math.log(0.5)))  # held at the ceiling
    assert -2.0 < float(log_std[0].detach()) < math.log(0.5)  # rose by three steps of lr
    _, scale = agent.policy_head(torch.zeros(1, agent.encoder.latent_dim))
    assert float(scale.max()) == pytest.approx(0.5)
    assert make_std_ceiling(compose_cfg(["+exp=bounce_ppo"]), agent, optimizer) is None  # off by default
    for key, bad, message in (
        ("std_ceiling", 0, r"agent\.std_ceiling must be a standard deviation > 0 or null"),
        ("std_ceiling", "'low'", r"agent\.std_ceiling must be a standard deviation > 0 or null"),
        ("std_ceiling_frames", 1000, r"agent\.std_ceiling_frames must be \[begin, end\] frames"),
        ("std_ceiling_frames", "[200,100]", r"agent\.std_ceiling_frames must be \[begin, end\] frames"),
        ("std_ceiling_frames", "[0,1.5]", r"agent\.std_ceiling_frames must be \[begin, end\] frames"),
        ("std_ceiling_frames", "[0.9,0.6]", r"or fractions of total_frames, e\.g\. \[0\.6,0\.9\]"),
    ):
        with pytest.raises(ValueError, match=message):
            check_config(compose_cfg(["+exp=bounce_ppo", "agent.std_ceiling=0.3", f"agent.{key}={bad}"]))


def test_the_std_ceiling_window_in_fractions_of_total_frames_is_the_same_window_in_frames():
    agent = Agent(("prop",), P, A)
    ceiling = ["+exp=bounce_ppo", "agent.std_ceiling=0.25", "total_frames=2000000"]
    fractions = compose_cfg([*ceiling, "agent.std_ceiling_frames=[0.6,0.9]"])
    frames = compose_cfg([*ceiling, "agent.std_ceiling_frames=[1200000,1800000]"])
    by_fraction = make_std_ceiling(fractions, agent, make_optimizer(fractions, agent))
    by_frames = make_std_ceiling(frames, agent, make_optimizer(frames, agent))
    assert (by_fraction.begin, by_fraction.end) == (by_frames.begin, by_frames.end) == (1_200_000, 1_800_000)
    longer = compose_cfg([*ceiling, "agent.std_ceiling_frames=[0.6,0.9]", "total_frames=10000000"])
    stretched = make_std_ceiling(longer, agent, make_optimizer(longer, agent))
    assert (stretched.begin, stretched.end) == (6_000_000, 9_000_000)  # the window scales with the run


def test_effective_rank_by_hand():
    # rows +-e_i of R^4: the centred singular values are all equal, so the rank is 4
    eye = torch.eye(4)
    assert effective_rank(torch.cat([eye, -eye])) == pytest.approx(4.0, rel=1e-5)
    # singular values 3 : 1: p = (0.75, 0.25), exp(-(0.75 ln 0.75 + 0.25 ln 0.25)) = 1.7548
    two = torch.tensor([[3.0, 0.0], [-3.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    assert effective_rank(two) == pytest.approx(1.7548, abs=1e-4)
    line = torch.arange(6.0).unsqueeze(1) * torch.tensor([[1.0, 2.0, 3.0]])  # every state on one line
    assert effective_rank(line) == pytest.approx(1.0, abs=1e-3)
    assert effective_rank(torch.ones(1, 8)) == 0.0 and effective_rank(torch.ones(5, 8)) == 0.0  # no variation


def test_rollout_stats_give_the_training_episodes_physical_metrics():
    find = make_env("find", 1).base_env  # 5 s episodes: an unreached tolerance reads 5.0
    done = torch.tensor([[False, True], [False, False], [True, False]])  # worlds 0 and 2 end
    find_time = torch.full((3, 2, 3), 5.0)
    find_time[0, 1] = torch.tensor([1.5, 4.0, 5.0])  # world 0 reached 3 cm and 1 cm
    find_time[2, 0] = torch.tensor([2.5, 5.0, 5.0])  # world 2 reached 3 cm only
    nxt = {
        "reward": torch.ones(3, 2, 1),
        "done": done.unsqueeze(-1),
        "reward_terms": {"dist": torch.ones(3, 2)},
        "object_distance": torch.full((3, 2, 1), 0.1),
        "find_time": find_time,
    }
    batch = TensorDict(
        {"next": nxt, "loc": torch.zeros(3, 2, 9), LATENT_KEY: torch.randn(3, 2, 4)},
        [3, 2],
    )
    stats = rollout_stats(batch, torch.zeros(3), find.metric_columns(), find.physical_metrics)
    assert stats["episodes"] == 2 and stats["episode_return"] == 1.5  # returns 2 and 1
    assert stats["episode/reached_3cm"] == 1.0 and stats["episode/reached_1cm"] == 0.5
    assert stats["episode/reached_0.05cm"] == 0.0
    assert stats["episode/find_time_3cm"] == pytest.approx(2.0)


# ---------------------------------------------------------------------------- the proximal feature term


def test_feature_drift_by_hand():
    # differences [1, -2, 0, 0.5]: squares [1, 4, 0, 0.25], mean 5.25 / 4
    now, before = torch.tensor([[1.0, 0.0], [2.0, 0.5]]), torch.tensor([[0.0, 2.0], [2.0, 0.0]])
    assert float(feature_drift(now, before)) == pytest.approx(1.3125)


def test_proximal_feature_loss_by_hand_with_its_gradient_and_keys():
    before = torch.tensor([[0.0, 2.0], [2.0, 0.0]])
    now = torch.tensor([[1.0, 0.0], [2.0, 0.5]], requires_grad=True)
    td = TensorDict({"z": now, "z_rollout": before}, [2])
    out = ProximalFeatureLoss(coeff=2.0)(td)
    assert float(out["loss_proximal_feature"].detach()) == pytest.approx(2.0 * 1.3125)
    assert float(out["feature_drift"]) == pytest.approx(1.3125) and not out["feature_drift"].requires_grad
    out["loss_proximal_feature"].backward()
    # d/dz of 2 * sum (z - z_rollout)^2 / 4 = (z - z_rollout): pulls back toward the rollout's latent
    assert now.grad.flatten().tolist() == pytest.approx([1.0, -2.0, 0.0, 0.5])
    off = ProximalFeatureLoss(coeff=0.0)(td)
    assert float(off["loss_proximal_feature"]) == 0.0 and not off["loss_proximal_feature"].requires_grad
    assert float(off["feature_drift"]) == pytest.approx(1.3125)  # the diagnostic either way
    renamed = ProximalFeatureLoss(coeff=1.0)
    renamed.set_keys(latent="latent", rollout_latent="acting_latent")
    moved = td.clone()
    moved.rename_key_("z", "latent")
    moved.rename_key_("z_rollout", "acting_latent")
    assert float(renamed(moved)["feature_drift"]) == pytest.approx(1.3125)
    with pytest.raises(KeyError, match=r"no 'z_rollout' entry; name the right one with loss\.set_keys"):
        ProximalFeatureLoss(coeff=1.0)(td.exclude("z_rollout"))
    with pytest.raises(ValueError, match="differ in shape"):
        ProximalFeatureLoss(coeff=1.0)(TensorDict({"z": now, "z_rollout": before[:, :1]}, [2]))


def test_the_proximal_feature_term_holds_the_encoder_to_the_rollouts_latent():
    agent, loss_fn, _ = agent_and_ppo_loss()
    minibatch = ppo_minibatch(agent)
    with torch.no_grad():
        agent.encode(minibatch)  # the latent the policy wrote while acting, as in a rollout
    acting = minibatch["z"].clone()
    cfg = compose_cfg(["+exp=bounce_ppo", "agent.proximal_feature_coeff=3.0"])
    assert make_policy_terms(compose_cfg(["+exp=bounce_ppo"]), agent) == ()  # off by default: no extra work
    (term,) = make_policy_terms(cfg, agent)
    plain = minibatch_loss(agent, loss_fn, minibatch.clone())[0]
    total, losses, _ = minibatch_loss(agent, loss_fn, minibatch.clone(), terms=(term,))
    # the encoder has not moved since acting: no drift and no penalty
    assert float(losses["feature_drift"]) == 0.0 and float(total) == pytest.approx(float(plain))
    optimizer = torch.optim.SGD(agent.encoder.parameters(), lr=0.5)
    plain.backward()
    optimizer.step()  # the encoder moves: its latent drifts from the rollout's
    batch = minibatch.clone()
    plain = minibatch_loss(agent, loss_fn, minibatch.clone())[0].detach()
    total, losses, _ = minibatch_loss(agent, loss_fn, batch, terms=(term,))
    assert torch.equal(batch["z_rollout"], acting) and not torch.equal(batch["z"], acting)
    drift = float(((batch["z"] - acting) ** 2).mean())
    assert drift > 0 and float(losses["feature_drift"]) == pytest.approx(drift, rel=1e-5)
    assert float(total.detach()) == pytest.approx(float(plain) + 3.0 * drift, rel=1e-5)
    for bad in ("-1", "'strong'"):
        with pytest.raises(ValueError, match=r"agent\.proximal_feature_coeff must be a number >= 0"):
            check_config(compose_cfg(["+exp=bounce_ppo", f"agent.proximal_feature_coeff={bad}"]))


# ---------------------------------------------------------------------------- the rollout buffer


def test_the_buffer_keeps_only_what_a_minibatch_reads_and_the_update_is_the_same():
    """A real Bounce rollout (8 worlds, 16 steps): the buffer with ``minibatch_keys`` holds the
    observations, action, log-probability, advantage, value target and old value (and the
    acting-time latent only for the proximal feature term), and PPO's update from it is the
    update from the whole rollout, number for number."""
    cfg = compose_cfg(["+exp=bounce_ppo", *TINY, "agent.shared_encoder=false"])
    env = make_train_env(cfg)
    torch.manual_seed(0)
    agent = agent_for_env(cfg, env)
    with torch.no_grad():
        rollout = env.rollout(16, agent.policy, break_when_any_done=False, auto_cast_to_device=False)
    env.close()
    assert rollout.batch_size == (8, 16)
    loss_fn = make_ppo_loss(cfg, agent)
    keys = minibatch_keys(agent, loss_fn)
    expected = {"prop", "tactile", "action", "action_log_prob", "advantage", "value_target", "state_value"}
    assert set(keys) == expected
    (term,) = make_policy_terms(compose_cfg(["+exp=bounce_ppo", "agent.proximal_feature_coeff=1.0"]), agent)
    assert set(minibatch_keys(agent, loss_fn, (term,))) == expected | {"z"}
    results = []
    for kept in (None, keys):
        learner = copy.deepcopy(agent)
        loss = make_ppo_loss(cfg, learner)
        optimizer = make_optimizer(cfg, learner)
        params = [p for group in optimizer.param_groups for p in group["params"]]
        buffer = make_rollout_buffer(cfg)
        store_rollout(rollout.clone(), learner, make_advantage(cfg), buffer, keys=kept)
        stored = set(buffer[:].keys()) - {"index"}  # the buffer's own entry
        assert (stored == expected) if kept else ({"next", "z", "loc", "scale"} < stored)
        torch.manual_seed(1)  # the minibatches' order
        means, _ = ppo_update(cfg, buffer, learner, loss, optimizer, params)
        results.append((means, [p.detach().clone() for p in params]))
    (whole, whole_params), (selected, selected_params) = results
    assert whole["loss_objective"] != 0 and whole == selected
    assert all(torch.equal(a, b) for a, b in zip(whole_params, selected_params, strict=True))
