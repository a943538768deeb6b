import os

# Offscreen rendering on a machine without a display; must precede the first import of mujoco.
os.environ.setdefault("MUJOCO_GL", "egl")

import pytest
import torch


@pytest.fixture(autouse=True)
def _one_torch_thread():
    # Physics runs on its own C threads; these tiny tensors gain nothing from more torch threads.
    torch.set_num_threads(1)
