"""The observation transforms on hand-computed numbers, outside any env."""

import pytest
import torch
from tensordict import TensorDict

from roto_trl.transforms import BinariseContacts, LastAction, ScaleProprioception


def test_binarise_contacts_thresholds_and_keeps_raw_forces():
    td = TensorDict({"contact_force": torch.tensor([[0.0, 0.05, 0.2, 3.0]])}, [1])
    out = BinariseContacts(threshold=0.1)._call(td.clone())
    assert out["tactile"].tolist() == [[0.0, 0.0, 1.0, 1.0]]
    assert out["tactile"].dtype == torch.float32
    assert torch.equal(out["contact_force"], td["contact_force"])
    assert BinariseContacts()._call(td.clone())["tactile"].tolist() == [[0.0, 1.0, 1.0, 1.0]]


def test_binarise_contacts_rejects_a_negative_threshold():
    with pytest.raises(ValueError, match="contact threshold must be a force >= 0 N"):
        BinariseContacts(threshold=-1.0)


def test_scale_proprioception_maps_limits_to_unit_range_and_scales_velocity():
    low, high = torch.tensor([0.0, -1.0]), torch.tensor([2.0, 3.0])
    t = ScaleProprioception(low, high, vel_scale=0.2)
    td = TensorDict(
        {"joint_pos": torch.tensor([[0.0, 3.0], [1.0, 0.0]]), "joint_vel": torch.tensor([[5.0, -10.0]] * 2)},
        [2],
    )
    out = t._call(td)
    assert out["joint_pos"].tolist() == [[-1.0, 1.0], [0.0, -0.5]]
    assert out["joint_vel"].tolist() == [[1.0, -2.0]] * 2


def test_scale_proprioception_rejects_bad_limits():
    with pytest.raises(ValueError, match="high > low"):
        ScaleProprioception(torch.tensor([1.0]), torch.tensor([1.0]), 0.2)


def test_last_action_is_clipped_and_zeroed_only_for_envs_that_reset():
    t = LastAction(n_actions=2)
    first = t._reset(None, TensorDict({}, [3]))
    assert first["last_action"].tolist() == [[0.0, 0.0]] * 3
    act = TensorDict({"action": torch.tensor([[0.5, 2.0], [-3.0, 0.1], [0.2, 0.3]])}, [3])
    out = t._step(act, TensorDict({}, [3]))
    assert torch.allclose(out["last_action"], torch.tensor([[0.5, 1.0], [-1.0, 0.1], [0.2, 0.3]]))
    reset = TensorDict({"_reset": torch.tensor([[False], [True], [False]])}, [3])
    out = t._reset(reset, TensorDict({}, [3]))
    assert torch.allclose(out["last_action"], torch.tensor([[0.5, 1.0], [0.0, 0.0], [0.2, 0.3]]))
