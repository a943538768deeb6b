"""Self-supervised objectives: the maths by hand, the modules, EMA, the memory, the optimisers."""

import math

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.objectives import SoftUpdate

from roto_trl.data.memory import AuxMemory
from roto_trl.modules.agent import Agent
from roto_trl.objectives import (
    ForwardDynamicsLoss,
    FullReconstructionLoss,
    TactileForwardDynamicsLoss,
    TactileReconstructionLoss,
)
from roto_trl.objectives.functional import (
    auto_pos_weight,
    contact_bce,
    contact_confusion,
    latent_mse,
    rollout_latents,
)

P, T, A = 6, 4, 3


def encoder():
    torch.manual_seed(0)
    return TensorDictModule(nn.Sequential(nn.Linear(P, 8), nn.ELU()), in_keys=["prop"], out_keys=["z"])


def batch(shape=(5,)):
    g = torch.Generator().manual_seed(1)
    return TensorDict(
        {
            "prop": torch.randn(*shape, P, generator=g),
            "tactile": (torch.rand(*shape, T, generator=g) > 0.6).float(),
            "action": torch.rand(*shape, A, generator=g) * 2 - 1,
        },
        batch_size=shape,
    )


# ---------------------------------------------------------------------------- maths by hand


def test_contact_bce_by_hand():
    logits, target = torch.tensor([0.0, 2.0]), torch.tensor([1.0, 0.0])
    # 10 * -log(sigmoid(0)) = 10 ln 2 ; -log(1 - sigmoid(2)) = ln(1 + e^2)
    expected = (10 * math.log(2) + math.log(1 + math.e**2)) / 2
    assert float(contact_bce(logits, target, 10.0)) == pytest.approx(expected, rel=1e-6)


def test_auto_pos_weight_is_the_clamped_inverse_contact_rate():
    assert float(auto_pos_weight(torch.tensor([1.0, 0.0, 0.0, 0.0]))) == pytest.approx(4.0)
    assert float(auto_pos_weight(torch.zeros(8))) == pytest.approx(100.0)
    assert float(auto_pos_weight(torch.ones(8))) == pytest.approx(1.0)


def test_contact_confusion_by_hand():
    logits = torch.tensor([1.0, -1.0, 1.0, -1.0, 1.0])
    target = torch.tensor([1.0, 1.0, 0.0, 0.0, 0.0])  # tp 1, fn 1, fp 2, tn 1
    rates = {k: float(v) for k, v in contact_confusion(logits, target).items()}
    assert rates == pytest.approx(
        {"tpr": 0.5, "fnr": 0.5, "fpr": 2 / 3, "tnr": 1 / 3, "accuracy": 0.4, "precision": 1 / 3}
    )
    assert math.isnan(float(contact_confusion(torch.tensor([-1.0]), torch.tensor([0.0]))["precision"]))


def test_latent_mse_and_autoregressive_rollout_by_hand():
    assert float(latent_mse(torch.tensor([1.0, 2.0]), torch.tensor([1.0, 4.0]))) == pytest.approx(2.0)

    def add(x):  # f(z, a) = z + a
        return x[..., :1] + x[..., 1:]

    predicted = rollout_latents(add, torch.tensor([[1.0]]), torch.tensor([[[2.0], [3.0]]]))
    assert predicted.tolist() == [[[3.0], [6.0]]]  # 1 + 2, then (1 + 2) + 3: uses its own prediction


# ---------------------------------------------------------------------------- the modules


def test_tactile_reconstruction_loss_is_the_bce_of_its_decoder():
    loss = TactileReconstructionLoss(encoder(), T, latent_dim=8, pos_weight=10.0)
    td = batch()
    out = loss(td)
    logits = loss.tactile_decoder(loss.encode(td))
    assert float(out["loss_tactile"]) == pytest.approx(float(contact_bce(logits, td["tactile"], 10.0)))
    assert not out["accuracy"].requires_grad
    loss.set_keys(tactile="touch")
    with pytest.raises(KeyError):
        loss(td)
    assert float(loss(td.rename_key_("tactile", "touch"))["loss_tactile"]) == pytest.approx(
        float(out["loss_tactile"])
    )


def test_full_reconstruction_adds_the_prop_mse():
    loss = FullReconstructionLoss(encoder(), P, T, latent_dim=8)
    td = batch()
    out = loss(td)
    recon = loss.observation_decoder(loss.encode(td))
    assert float(out["loss_prop"]) == pytest.approx(float((recon[:, :P] - td["prop"]).square().mean()))
    assert float(out["loss_tactile"]) == pytest.approx(float(contact_bce(recon[:, P:], td["tactile"], 10.0)))


def test_forward_dynamics_loss_by_composition_and_ema():
    enc = encoder()
    loss = ForwardDynamicsLoss(enc, A, latent_dim=8)
    update = SoftUpdate(loss, tau=0.01)
    seq = batch((4, 3))  # 4 runs of n = 3 steps
    out = loss(seq)
    z0 = loss.encode(seq[:, 0])
    predicted = rollout_latents(loss.forward_model, z0, seq["action"][:, :-1])
    target = enc(seq[:, 1:].clone())["z"]  # the target encoder starts equal to the encoder
    expected = sum(latent_mse(loss.projector(predicted[:, i]), target[:, i]) for i in range(2))
    assert float(out["loss_dynamics"]) == pytest.approx(float(expected), rel=1e-5)
    assert set(out.keys()) >= {"mse_h1", "mse_h2"}
    # EMA: after a step of the encoder, the target moves 1 % of the way
    weight = enc.module[0].weight
    before = loss.target_encoder_network_params["module", "0", "weight"].clone()
    with torch.no_grad():
        weight.add_(1.0)
    update.step()
    after = loss.target_encoder_network_params["module", "0", "weight"]
    assert torch.allclose(after, before + 0.01 * (weight.detach() - before), atol=1e-6)
    with pytest.raises(ValueError, match="sequences"):
        loss(batch((4,)))


def test_tfd_tactile_term_is_live():
    loss = TactileForwardDynamicsLoss(encoder(), A, T, latent_dim=8)
    out = loss(batch((4, 3)))
    out["loss_tactile"].backward()
    grads = {
        "forward model": loss.forward_model[1].weight.grad,
        "tactile decoder": loss.tactile_decoder[1].weight.grad,
    }
    for name, grad in grads.items():
        assert grad is not None and float(grad.abs().sum()) > 0, name
    assert {"tpr_h1", "tpr_h2", "precision_h2", "loss_dynamics"} <= set(out.keys())


def test_ppo_and_auxiliary_optimisers_hold_the_right_parameters():
    from roto_trl.trainers.auxiliary import AuxiliaryUpdate

    agent = Agent(("prop", "tactile"), P + T, A)
    loss = TactileReconstructionLoss(agent.common, T)
    memory = AuxMemory(1, ("prop", "tactile"))
    rollout = batch((2, 4))
    rollout["next"] = TensorDict({"done": torch.zeros(2, 4, 1, dtype=torch.bool)}, [2, 4])
    memory.add(rollout)
    aux = AuxiliaryUpdate(loss, memory, lr=1e-2, coeff=1.0, batch=6)
    ppo_params = {id(p) for p in agent.parameters()}
    aux_params = {id(p) for g in aux.optimizer.param_groups for p in g["params"]}
    encoder_params = {id(p) for p in agent.encoder.parameters()}
    heads = {id(p) for m in (agent.policy_head, agent.value_head) for p in m.parameters()}
    decoder = {id(p) for p in loss.tactile_decoder.parameters()}
    assert encoder_params <= ppo_params and encoder_params <= aux_params
    assert not heads & aux_params and not decoder & ppo_params and decoder <= aux_params
    # one auxiliary step changes the encoder and decoder, never the heads
    snapshot = {name: p.detach().clone() for name, p in agent.named_parameters()}
    dec_before = loss.tactile_decoder[1].weight.detach().clone()
    aux.step()
    changed = {name for name, p in agent.named_parameters() if not torch.equal(p, snapshot[name])}
    assert any(n.startswith("encoder.") for n in changed)
    assert not any(n.startswith(("policy_head.", "value_head.")) for n in changed)
    assert not torch.equal(loss.tactile_decoder[1].weight, dec_before)


# ---------------------------------------------------------------------------- the memory


def rollout(value: float, dones=(), envs: int = 2, steps: int = 6):
    done = torch.zeros(envs, steps, 1, dtype=torch.bool)
    for env, t in dones:
        done[env, t] = True
    return TensorDict(
        {
            "prop": value + torch.arange(steps, dtype=torch.float32).view(1, steps, 1).expand(envs, steps, P),
            "tactile": torch.ones(envs, steps, T),
            "action": torch.zeros(envs, steps, A),
            "next": TensorDict({"done": done}, [envs, steps]),
        },
        [envs, steps],
    )


def test_memory_is_fifo_and_stores_contacts_compactly():
    memory = AuxMemory(2, ("prop", "tactile"))
    for value in (0.0, 100.0, 200.0):
        memory.add(rollout(value))
    starts = sorted(float(v) for v in memory.stored()["prop"][:, 0, 0, 0])
    assert starts == [100.0, 200.0]  # the oldest rollout left
    assert memory.stored()["tactile"].dtype == torch.uint8
    # float32 prop and action, uint8 contacts, bool done, and the buffer's int64 index
    per_step = P * 4 + T * 1 + A * 4 + 1 + 8
    assert memory.nbytes() == 2 * 2 * 6 * per_step
    assert memory.sample(5)["tactile"].dtype == torch.float32


def test_sequences_never_cross_an_episode_end():
    memory = AuxMemory(1, ("prop", "tactile"))
    memory.add(rollout(0.0, dones=[(0, 2), (1, 0)]))
    valid = memory.valid_starts(3)[0]
    # env 0: done at step 2 -> runs starting at 1 or 2 would continue past it
    assert valid[0].tolist() == [True, False, False, True, False, False]
    assert valid[1].tolist() == [False, True, True, True, False, False]
    seq = memory.sample_sequences(64, 3, generator=torch.Generator().manual_seed(0))
    steps = seq["prop"][..., 0]
    assert torch.equal(steps[:, 1:] - steps[:, :-1], torch.ones(64, 2))  # consecutive steps
    with pytest.raises(ValueError, match="no run of 7 steps"):
        memory.sample_sequences(4, 7)


def test_auxiliary_step_waits_for_runs_of_n_steps():
    from roto_trl.trainers.auxiliary import AuxiliaryUpdate

    memory = AuxMemory(1, ("prop", "tactile"))
    memory.add(rollout(0.0, dones=[(0, 1), (0, 3), (1, 1), (1, 3)]))  # episodes of at most 2 steps
    loss = ForwardDynamicsLoss(encoder(), A, latent_dim=8)
    aux = AuxiliaryUpdate(loss, memory, lr=1e-3, coeff=1.0, batch=8, seq_len=3)
    before = [p.detach().clone() for p in loss.parameters()]
    assert aux.step() is None
    assert all(torch.equal(a, b) for a, b in zip(before, loss.parameters(), strict=True))
    memory.add(rollout(10.0))  # a rollout without episode ends replaces it
    stats = aux.step()
    assert stats is not None and math.isfinite(stats["loss_dynamics"])
