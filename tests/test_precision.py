"""``agent.precision``: the networks' hidden layers' products in bfloat16, their outputs and
parameters in float32, the same checkpoint keys, and a run that trains, evaluates and reloads
with it."""

import pytest
import torch
from helpers import TINY, compose_cfg
from omegaconf import OmegaConf
from tensordict import TensorDict

from roto_trl.config import compose_train, settle_for_machine, typed_config
from roto_trl.modules.agent import Agent
from roto_trl.modules.networks import cpu_has_bfloat16, hidden_precision, resolved_precision
from roto_trl.train import train
from roto_trl.trainers.checkpoint import LATEST, load_checkpoint

P, A = 12, 4


def agents(shared: bool):
    """A float32 and a bfloat16 agent with the same weights."""
    torch.manual_seed(0)
    critic = None if shared else [64, 32]
    fp32 = Agent(("prop",), P, A, shared_encoder=shared, critic_encoder_sizes=critic)
    bf16 = Agent(("prop",), P, A, shared_encoder=shared, critic_encoder_sizes=critic, precision="bfloat16")
    bf16.load_state_dict(fp32.state_dict())
    return fp32, bf16


def observations(n: int) -> TensorDict:
    return TensorDict({"prop": torch.randn(n, P)}, [n])


def outputs(agent, obs: torch.Tensor):
    """The policy's mean, the value and the gradient of a loss on both w.r.t. every parameter."""
    agent.zero_grad()
    loc = agent.policy(TensorDict({"prop": obs}, obs.shape[:1]))["loc"]
    value = agent.value(TensorDict({"prop": obs}, obs.shape[:1]))["state_value"]
    with hidden_precision(agent.encoder.precision):  # as minibatch_step
        (loc.square().sum() + value.square().sum()).backward()
    grads = torch.cat([p.grad.flatten() for p in agent.parameters() if p.grad is not None])
    return loc, value, grads


@pytest.mark.parametrize("shared", [True, False])
def test_bfloat16_hidden_layers_give_float32_outputs_near_float32s(shared):
    fp32, bf16 = agents(shared)
    obs = torch.randn(256, P)
    loc32, value32, grads32 = outputs(fp32, obs)
    loc16, value16, grads16 = outputs(bf16, obs)
    assert loc16.dtype == value16.dtype == grads16.dtype == torch.float32
    assert torch.backends.mkldnn.matmul.fp32_precision == "none"  # restored after the forward
    if cpu_has_bfloat16():  # elsewhere oneDNN may keep float32 products
        assert not torch.equal(loc16, loc32)  # the hidden layers did multiply in bfloat16
    # bfloat16 keeps 8 bits: ~0.4 % per factor, averaged over each layer's sums
    assert (loc16 - loc32).abs().max() < 2e-2
    assert (value16 - value32).abs().max() < 2e-2 * value32.abs().max() + 1e-3
    cosine = torch.nn.functional.cosine_similarity(grads16, grads32, dim=0)
    assert cosine > 0.99
    assert all(p.dtype == torch.float32 for p in bf16.parameters())


def test_the_hidden_layers_and_the_backward_multiply_in_bfloat16_and_the_output_layers_in_float32():
    _, agent = agents(shared=True)
    seen = {}

    def record(name):
        def hook(module, *_):
            seen[name] = torch.backends.mkldnn.matmul.fp32_precision

        return hook

    agent.encoder.net[0].register_forward_hook(record("first encoder layer"))
    agent.policy_head.body[0].register_forward_hook(record("policy hidden layer"))
    agent.policy_head.mean.register_forward_hook(record("policy output layer"))
    agent.value_head.net[1].register_forward_hook(record("value output layer"))
    agent.encoder.net[0].weight.register_hook(lambda grad: record("backward")(None))
    td = agent.policy(observations(8))
    value = agent.value(observations(8))["state_value"]
    assert seen == {
        "first encoder layer": "bf16",
        "policy hidden layer": "bf16",
        "policy output layer": "none",
        "value output layer": "none",
    }
    before = torch.backends.mkldnn.matmul.fp32_precision
    with hidden_precision("bfloat16"):  # as minibatch_step runs the backward
        (td["loc"].sum() + value.sum()).backward()
    assert seen["backward"] == "bf16"
    assert torch.backends.mkldnn.matmul.fp32_precision == before == "none"


def test_float32_changes_nothing_and_bfloat16_restores_the_setting_after_an_error():
    fp32, bf16 = agents(shared=False)
    assert fp32.state_dict().keys() == bf16.state_dict().keys()
    with hidden_precision("float32"):
        assert torch.backends.mkldnn.matmul.fp32_precision == "none"
    with pytest.raises(RuntimeError, match="inside"), hidden_precision("bfloat16"):
        assert torch.backends.mkldnn.matmul.fp32_precision == "bf16"
        raise RuntimeError("inside")
    assert torch.backends.mkldnn.matmul.fp32_precision == "none"


def test_a_bad_precision_is_a_one_line_error():
    with pytest.raises(ValueError, match=r"agent\.precision must be one of float32, bfloat16, got 'float16'"):
        Agent(("prop",), P, A, precision="float16")
    with pytest.raises(
        ValueError, match=r"agent\.precision must be one of float32, bfloat16, auto, got fp16"
    ):
        compose_cfg(["+exp=bounce_ppo", "agent.precision=fp16"])
    with pytest.raises(ValueError, match=r"got 'auto'"):  # the networks take a resolved value only
        Agent(("prop",), P, A, precision="auto")
    for device in ("cuda", "tpu"):  # a one-line error, also before the device itself is checked
        with pytest.raises(ValueError, match=f"with device={device} use float32"):
            compose_cfg(["+exp=bounce_ppo", "agent.precision=bfloat16", f"device={device}"])


def test_a_bfloat16_run_trains_evaluates_and_its_checkpoint_reloads(tmp_path):
    run = tmp_path / "bf16"
    train(compose_cfg(["+exp=bounce_ppo", *TINY, "agent.precision=bfloat16", f"run_dir={run}"]))
    state = load_checkpoint(run / "checkpoints" / LATEST)
    networks = {k: t for k, t in state["agent"].items() if not k.startswith("value_norm.")}
    assert {t.dtype for t in networks.values()} == {torch.float32}
    assert state["config"]["agent"]["precision"] == "bfloat16"  # evaluation rebuilds it as trained
    assert (run / "summary.json").is_file()


def test_auto_is_bfloat16_only_on_a_cpu_with_bfloat16_products():
    on_this_cpu = "bfloat16" if cpu_has_bfloat16() else "float32"
    assert resolved_precision("auto", "cpu") == on_this_cpu
    assert resolved_precision("auto", "cuda:0") == "float32"
    assert resolved_precision("auto", "tpu") == "float32"  # check_device names the bad device
    assert [resolved_precision(p, "cuda") for p in ("float32", "bfloat16")] == ["float32", "bfloat16"]
    cfg = typed_config(compose_train(["+exp=bounce_ppo", "agent.precision=auto", "device=cuda"]))
    notes = settle_for_machine(cfg)  # as train() does before it saves the run's config
    assert cfg.agent.precision == "float32"
    assert "agent.precision: auto -> float32 (device=cuda: bfloat16 products are a CPU path)" in notes


def test_an_auto_run_saves_the_precision_it_ran(tmp_path, capsys):
    run = tmp_path / "auto"
    train(compose_cfg(["+exp=bounce_ppo", *TINY, "agent.precision=auto", f"run_dir={run}"]))
    on_this_cpu = "bfloat16" if cpu_has_bfloat16() else "float32"
    with_or_without = "with" if cpu_has_bfloat16() else "without"
    said = f"auto -> {on_this_cpu} (device=cpu: a CPU {with_or_without} bfloat16 products in hardware)"
    assert f"agent.precision: {said}" in capsys.readouterr().out
    assert OmegaConf.load(run / "config.yaml").agent.precision == on_this_cpu
    assert load_checkpoint(run / "checkpoints" / LATEST)["config"]["agent"]["precision"] == on_this_cpu
