"""The composability example: our ForwardDynamicsLoss inside a stock TorchRL PPO on Pendulum."""

import importlib.util
import math
from pathlib import Path

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "ssl_with_torchrl_ppo.py"


def test_example_trains_a_few_iterations():
    assert len(EXAMPLE.read_text().splitlines()) < 60
    spec = importlib.util.spec_from_file_location("ssl_example", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    history = module.main(iterations=4, frames=256)
    assert len(history) == 4
    assert all(math.isfinite(h["fd"]) and math.isfinite(h["reward"]) for h in history)
    assert history[-1]["fd"] < history[0]["fd"]  # the forward model learns
