"""TensorModule writes tensor outputs without ``TensorDict.from_any`` and otherwise behaves as
``TensorDictModule`` (roto_trl/modules/tensor_writes.py)."""

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn

from roto_trl.modules.agent import Agent
from roto_trl.modules.tensor_writes import TensorModule


class TwoOutputs(nn.Module):
    def forward(self, x):
        return x + 1.0, 2.0 * x


def inputs():
    return TensorDict({"x": torch.arange(6.0).reshape(3, 2)}, [3])


@pytest.mark.parametrize("inplace", [True, False, "empty"])
def test_same_outputs_as_tensordictmodule(inplace):
    keys = dict(in_keys=["x"], out_keys=["a", "b"], inplace=inplace)
    ours = TensorModule(TwoOutputs(), **keys)(inputs())
    reference = TensorDictModule(TwoOutputs(), **keys)(inputs())
    assert set(ours.keys()) == set(reference.keys())
    assert (ours == reference).all()
    assert ("x" in ours) == (inplace is True)


def test_an_output_key_of_underscore_is_dropped():
    out = TensorModule(TwoOutputs(), in_keys=["x"], out_keys=["a", "_"])(inputs())
    assert set(out.keys()) == {"x", "a"}


def test_a_dict_output_takes_tensordicts_own_path():
    module = TensorModule(lambda x: {"y": x * 3.0}, in_keys=["x"], out_keys=["y"])
    assert torch.equal(module(inputs())["y"], inputs()["x"] * 3.0)


def test_the_agent_acts_and_values_without_from_any(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("TensorDict.from_any was called")

    for shared in (True, False):
        agent = Agent(("prop",), 5, 3, shared_encoder=shared)
        td = TensorDict({"prop": torch.randn(4, 5)}, [4])
        with monkeypatch.context() as patch:
            patch.setattr(TensorDict, "from_any", refuse)
            out = agent.value(agent.policy(td))
        assert out["action"].shape == (4, 3) and out["state_value"].shape == (4, 1)
