"""TensorDict modules that write their tensor outputs into the tensordict as they are.

``TensorDictModule`` passes every output through ``TensorDict.from_any``, which in tensordict
0.14 asks ``importlib.util.find_spec("pandas")`` each time (to recognise a DataFrame). Without
pandas in ``sys.modules`` that is a search of the import path, three times per control step
while acting and again in every minibatch of the update (docs/throughput.md).
For a tensor ``from_any`` returns the tensor itself, so these modules set tensors directly and
leave anything else (a dict, a tuple of tensors) to ``TensorDictModule``'s own path.
"""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule
from torchrl.modules import ValueOperator


class TensorWritesMixin:
    """Writes the module's tensor outputs with ``set``; other outputs take the parent's path."""

    def _write_to_tensordict(self, tensordict, tensors, tensordict_out=None, out_keys=None):
        keys = self.out_keys_source if out_keys is None else out_keys
        if len(tensors) != len(keys) or not all(isinstance(t, torch.Tensor) for t in tensors):
            return super()._write_to_tensordict(tensordict, tensors, tensordict_out, out_keys)
        # the parent with nothing to write picks the output tensordict (in place, empty or new)
        out = super()._write_to_tensordict(tensordict, [], tensordict_out, [])
        for key, tensor in zip(keys, tensors, strict=True):
            if key != "_":
                out.set(key, tensor)
        return out


class TensorModule(TensorWritesMixin, TensorDictModule):
    """``TensorDictModule`` that writes tensor outputs directly (see the module docstring)."""


class TensorValueOperator(TensorWritesMixin, ValueOperator):
    """TorchRL's ``ValueOperator`` that writes its value directly (see the module docstring)."""
