import pytest
import torch


@pytest.fixture(autouse=True)
def _one_torch_thread():
    # Physics runs on its own C threads; these tiny tensors gain nothing from more torch threads.
    torch.set_num_threads(1)
