"""Self-supervised objectives: the maths by hand, the modules, the target encoder, the memory."""

import math

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.objectives import SoftUpdate

from roto_trl.data.memory import AuxMemory
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


def test_target_encoder_stays_out_of_the_graph_whatever_the_order():
    enc = encoder()
    loss = ForwardDynamicsLoss(enc, A, latent_dim=8)
    seq = batch((4, 3))
    loss(seq)  # a forward pass first, THEN the target updater
    targets = loss.target_encoder_network_params
    assert not any(t.requires_grad for t in targets.values(True, True))
    update = SoftUpdate(loss, tau=0.01)
    optimizer = torch.optim.SGD(loss.parameters(), lr=0.1)
    before = targets["module", "0", "weight"].clone()
    gap_before = float((enc.module[0].weight - before).abs().sum())
    assert gap_before == 0.0  # the target starts as a copy of the encoder
    loss(seq)["loss_dynamics"].backward()
    optimizer.step()
    update.step()
    online, after = enc.module[0].weight.detach(), targets["module", "0", "weight"]
    assert torch.allclose(after, before + 0.01 * (online - before), atol=1e-7)
    assert not torch.equal(after, before)
    assert not any(t.requires_grad for t in targets.values(True, True))


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


def test_memory_keeps_the_applied_action():
    memory = AuxMemory(1, ("prop",), action_bounds=(-1.0, 1.0))
    data = rollout(0.0)
    data["action"] = torch.tensor([-3.0, -0.5, 2.0]).expand(2, 6, A).clone()  # a wide Gaussian's samples
    memory.add(data)
    assert memory.stored()["action"][0, 0, 0].tolist() == [-1.0, -0.5, 1.0]


def test_minibatches_cover_the_memory_once_in_disjoint_parts():
    memory = AuxMemory(1, ("prop", "tactile"))
    memory.add(rollout(0.0))  # 2 worlds x 6 steps; prop[..., 0] is the step index
    parts = list(memory.minibatches(4, generator=torch.Generator().manual_seed(0)))
    assert [p.shape[0] for p in parts] == [3, 3, 3, 3]
    steps = sorted(float(v) for p in parts for v in p["prop"][:, 0])
    assert steps == sorted([float(t) for t in range(6)] * 2)  # every step once
    assert parts[0]["tactile"].dtype == torch.float32
    assert len(list(memory.minibatches(100))) == 12  # never an empty minibatch


def test_sequences_never_cross_an_episode_end():
    memory = AuxMemory(1, ("prop", "tactile"))
    memory.add(rollout(0.0, dones=[(0, 2), (1, 0)]))
    valid = memory.valid_starts(3)[0]
    # env 0: done at step 2 -> runs starting at 1 or 2 would continue past it
    assert valid[0].tolist() == [True, False, False, True, False, False]
    assert valid[1].tolist() == [False, True, True, True, False, False]
    # a pass takes the valid runs on one grid of stride 3: starts {0, 3}, {1, 4} or {2, 5}
    by_grid = {0: [0.0, 3.0, 3.0], 1: [1.0], 2: [2.0]}
    seen = set()
    for seed in range(12):
        parts = list(memory.minibatches(2, 3, generator=torch.Generator().manual_seed(seed)))
        steps = torch.cat([p["prop"][..., 0] for p in parts])  # [runs, 3]
        assert torch.equal(steps[:, 1:] - steps[:, :-1], torch.ones(len(steps), 2))  # consecutive steps
        starts = sorted(steps[:, 0].tolist())
        assert starts == by_grid[int(starts[0]) % 3]  # no step in two runs of one pass
        seen.add(int(starts[0]) % 3)
    assert seen == {0, 1, 2}  # every valid run comes up over the passes
    assert list(memory.minibatches(2, 7)) == []


def test_auxiliary_update_waits_for_runs_of_n_steps():
    from roto_trl.trainers.auxiliary import AuxiliaryUpdate

    memory = AuxMemory(1, ("prop", "tactile"))
    memory.add(rollout(0.0, dones=[(0, 1), (0, 3), (1, 1), (1, 3)]))  # episodes of at most 2 steps
    loss = ForwardDynamicsLoss(encoder(), A, latent_dim=8)
    aux = AuxiliaryUpdate(loss, memory, lr=1e-3, coeff=1.0, seq_len=3)
    assert list(aux.epoch(4)) == []
    memory.add(rollout(10.0))  # a rollout without episode ends replaces it
    parts = list(aux.epoch(4))
    runs = sum(p.shape[0] for p in parts)  # 2 worlds x the grid's starts: {0, 3}, {1} or {2}
    assert runs in (2 * 2, 2 * 1) and len(parts) == min(4, runs)
    total, stats = aux.objective(parts[0])
    assert total.requires_grad and math.isfinite(stats["loss_dynamics"])
