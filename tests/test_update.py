"""The PPO update: entropy and log-std conventions, the paper's Eq. 2 with an SSL objective, the
two optimisers, the auxiliary minibatches, the KL-adaptive learning rate and the CPU profile's
settings."""

import copy
import math

import pytest
import torch
from helpers import TINY, compose_cfg
from omegaconf import OmegaConf
from tensordict import TensorDict

from roto_trl import make_env
from roto_trl.config import settle_for_machine
from roto_trl.data.memory import AuxMemory
from roto_trl.modules.agent import LATENT_KEY, Agent
from roto_trl.objectives import TactileForwardDynamicsLoss
from roto_trl.train import train
from roto_trl.trainers.auxiliary import AuxiliaryUpdate
from roto_trl.trainers.builders import (
    agent_for_env,
    make_advantage,
    make_eval_env,
    make_lr_schedule,
    make_optimizer,
    make_ppo_loss,
    make_train_env,
    make_update,
)
from roto_trl.trainers.loggers import read_csv
from roto_trl.trainers.lr_schedule import kl_adaptive_lr, kl_k3
from roto_trl.trainers.ppo import effective_rank, minibatch_keys, minibatch_loss, rollout_stats, saturation

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
    for bad in ("-0.1", "high"):
        with pytest.raises(ValueError, match=r"agent\.entropy_coeff"):
            compose_cfg(["+exp=find_fd", f"agent.entropy_coeff={bad}"])


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
        compose_cfg(["+exp=bounce_ppo", "agent.critic_encoder_sizes=[64]"])
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
    """One recipe per task, the same for every variant: Bounce's decays the weights (AdamW),
    Find's and Baoding's do not (plain Adam); Find's evaluates on 128 worlds (its 0/1 metric needs
    them), Bounce's and Baoding's on 32; no variant has another Adam eps;
    Bounce's and Baoding's matrix products are ``auto`` (bfloat16 where the CPU has them), Find's
    float32."""
    agent = Agent(("prop",), P, A)
    built = {}
    for exp in ("bounce_ppo", "bounce_fd", "find_ppo", "find_fd", "baoding_fd_mem"):
        cfg = compose_cfg([f"+exp={exp}", "+profile=cpu", "total_frames=2000000"])
        optimizer = make_optimizer(cfg, agent)
        decay = optimizer.param_groups[0]["weight_decay"]
        eps = optimizer.param_groups[0]["eps"]
        built[exp] = (type(optimizer).__name__, decay, eps, cfg.eval.num_envs, cfg.agent.precision)
    assert built == {
        "bounce_ppo": ("AdamW", 3.0, 1e-8, 32, "auto"),
        "bounce_fd": ("AdamW", 3.0, 1e-8, 32, "auto"),
        "find_ppo": ("Adam", 0.0, 1e-8, 128, "float32"),
        "find_fd": ("Adam", 0.0, 1e-8, 128, "float32"),
        "baoding_fd_mem": ("Adam", 0.0, 1e-8, 32, "auto"),
    }
    assert compose_cfg(["+exp=bounce_ppo"]).agent.precision == "float32"  # the paper's run
    kept = compose_cfg(["+exp=bounce_ppo", "+profile=cpu", "agent.precision=float32"])
    assert kept.agent.precision == "float32"  # the command line wins
    paper = compose_cfg(["+exp=bounce_ppo"])
    assert (paper.agent.weight_decay, paper.eval.num_envs) == (0.0, 100)  # the paper's: train.yaml's
    off = compose_cfg(["+exp=bounce_ppo", "+profile=cpu", "agent.weight_decay=0"])
    assert isinstance(make_optimizer(off, agent), torch.optim.Adam)  # the command line wins
    find = compose_cfg(["+exp=find_ppo", "+profile=cpu", "agent.weight_decay=1.0"])
    assert make_optimizer(find, agent).param_groups[0]["weight_decay"] == 1.0
    assert compose_cfg(["+exp=find_ppo", "+profile=cpu", "eval.num_envs=64"]).eval.num_envs == 64
    find = compose_cfg(["+exp=find_ppo", "+profile=cpu", "+env.overrides.num_threads=1"])
    env = make_eval_env(find)
    assert env.batch_size == torch.Size([128])
    env.close()


def test_the_cpu_profile_lengthens_only_rollouts_under_32_steps(tmp_path):
    notes = []
    for exp, paper, recipe in (("bounce_ppo", 16, 32), ("find_ppo", 32, 32), ("find_fd", 64, 64)):
        cfg = compose_cfg([f"+exp={exp}", "+profile=cpu", "agent.precision=float32"])
        notes += settle_for_machine(cfg)
        assert cfg.agent.rollout_len == recipe
        cfg = compose_cfg([f"+exp={exp}"])
        assert not settle_for_machine(cfg)  # the paper's exps have no floor
        assert cfg.agent.rollout_len == paper
    assert notes == [
        "agent.rollout_len: 16 -> 32 (agent.min_rollout_len; agent.min_rollout_len=null keeps 16)"
    ]
    kept = compose_cfg(["+exp=bounce_ppo", "+profile=cpu", "agent.min_rollout_len=null"])
    settle_for_machine(kept)
    assert kept.agent.rollout_len == 16
    with pytest.raises(ValueError, match=r"agent\.min_rollout_len must be >= 1, got 0"):
        compose_cfg(["+exp=bounce_ppo", "agent.min_rollout_len=0"])
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
        out = make_ppo_loss(cfg, agent)(agent.encode(td))
        assert float(out["loss_critic"].detach()) == pytest.approx(expected, rel=1e-5)
        assert (out.get("value_clip_fraction", None) is not None) == (clip_value != "null")
    for bad in ("0", "-0.1"):
        with pytest.raises(ValueError, match=r"agent\.clip_value must be > 0, got"):
            compose_cfg(["+exp=bounce_ppo", f"agent.clip_value={bad}"])


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
        td = rollout()
        make_advantage(cfg)(td)
        assert td["advantage"].flatten().tolist() == pytest.approx(advantages, abs=1e-4)
        assert td["value_target"].flatten().tolist() == pytest.approx([2.5, 3.0])
        assert make_ppo_loss(cfg, agent).normalize_advantage == (scope == "minibatch")  # in the loss
    names_the_choices = r"agent\.normalize_advantage must be one of minibatch, batch, none, got rollout"
    with pytest.raises(ValueError, match=names_the_choices):
        compose_cfg(["+exp=bounce_ppo", "agent.normalize_advantage=rollout"])


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
    with pytest.raises(ValueError, match=r"agent\.lr_schedule must be one of fixed, kl_adaptive, got cosine"):
        compose_cfg(["+exp=bounce_ppo", "agent.lr_schedule=cosine"])


def test_adam_and_adamw_take_torchs_eps():
    agent = Agent(("prop",), P, A)
    for decay in ("0.0", "1.0"):
        cfg = compose_cfg(["+exp=bounce_ppo", f"agent.weight_decay={decay}"])
        assert {g["eps"] for g in make_optimizer(cfg, agent).param_groups} == {1e-8}


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
    assert optimizer.param_groups[1]["params"][-1] is agent.policy_head.log_std  # where checkpoints hold it
    critic = Agent(("prop",), P, A, shared_encoder=False, critic_encoder_sizes=[8])
    decayed = make_optimizer(cfg, critic).param_groups[0]["params"]
    assert {id(p) for p in decayed} == {id(p) for p in critic.parameters() if p.dim() >= 2}  # every part
    for bad in ("-0.1", "a"):
        with pytest.raises(ValueError, match=r"agent\.weight_decay"):
            compose_cfg(["+exp=bounce_ppo", f"agent.weight_decay={bad}"])


def test_the_forward_model_learns_from_the_action_the_env_applied():
    from roto_trl.trainers.builders import agent_for_env, make_aux_update, make_collector, make_train_env

    cfg = compose_cfg(["+exp=bounce_fd", "env.num_envs=2", "agent.rollout_len=3", "agent.minibatches=2"])
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
    # both optimisers are PyTorch's fused Adam
    assert aux.optimizer.defaults["fused"] and make_optimizer(cfg, agent).defaults["fused"]


def test_the_initial_log_std_is_configurable_and_the_papers_is_zero():
    assert compose_cfg(["+exp=bounce_ppo"]).agent.init_log_std == 0.0
    agent = Agent(("prop",), P, A, init_log_std=-1.0)
    _, scale = agent.policy_head(torch.zeros(3, agent.encoder.latent_dim))
    torch.testing.assert_close(scale, torch.full((3, A), math.exp(-1.0)))


def test_mean_saturation_is_the_share_of_the_tanh_means_entries_past_0_9():
    # every run logs the saturation of the loc the policy wrote while acting: 2 of these 4 > 0.9
    assert saturation(torch.tensor([[0.95, -0.2], [-0.91, 0.9]])) == pytest.approx(0.5)


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


# ---------------------------------------------------------------------------- the rollout buffer


def test_the_buffer_keeps_only_what_a_minibatch_reads_and_the_update_is_the_same():
    """A real Bounce rollout (8 worlds, 16 steps): the update's buffer holds the observations,
    action, log-probability, advantage, value target and old value (``minibatch_keys``), and
    PPO's update from it is the update from the whole rollout, number for number."""
    cfg = compose_cfg(["+exp=bounce_ppo", *TINY, "agent.shared_encoder=false"])
    env = make_train_env(cfg)
    torch.manual_seed(0)
    agent = agent_for_env(cfg, env)
    with torch.no_grad():
        rollout = env.rollout(16, agent.policy, break_when_any_done=False, auto_cast_to_device=False)
    assert rollout.batch_size == (8, 16)
    expected = {"prop", "tactile", "action", "action_log_prob", "advantage", "value_target", "state_value"}
    assert set(minibatch_keys(agent, make_ppo_loss(cfg, agent))) == expected
    results = []
    for whole in (True, False):
        update = make_update(cfg, copy.deepcopy(agent), env)
        if whole:
            update.keys = [*rollout.keys(True, True), "advantage", "value_target", "state_value"]
        update.store(rollout.clone())
        stored = set(update.buffer[:].keys()) - {"index"}  # the buffer's own entry
        assert ({"next", "z", "loc", "scale"} < stored) if whole else (stored == expected)
        torch.manual_seed(1)  # the minibatches' order
        means, _ = update.update()
        results.append((means, [p.detach().clone() for p in update.params]))
    env.close()
    (whole, whole_params), (selected, selected_params) = results
    assert whole["loss_objective"] != 0 and whole == selected
    assert all(torch.equal(a, b) for a, b in zip(whole_params, selected_params, strict=True))
