"""The benchmarks keep running as the trainer and the env change (their speeds are not checked here)."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from roto_trl.modules.networks import resolved_precision

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
pytestmark = pytest.mark.slow  # each starts a benchmark process that trains or steps for seconds


def test_train_throughput_measures_an_ssl_experiment_with_the_cpu_recipe():
    command = [
        sys.executable,
        str(BENCHMARKS / "train_throughput.py"),
        *("--exps", "bounce_fd", "--num-envs", "16", "--iterations", "2", "--no-peers", "--profile", "cpu"),
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "profile cpu;" in done.stdout.splitlines()[0]
    row = next(line for line in done.stdout.splitlines() if line.startswith("bounce_fd"))
    ours, sim, update, limit, ratio, act, ratio_with_acting, rounds = row.split()[2:10]
    ours, sim, update, limit, act = (float(v.replace(",", "")) for v in (ours, sim, update, limit, act))
    assert min(ours, sim, update, limit, act) > 0
    assert re.fullmatch(r"\d+\.\d\d", ratio) and re.fullmatch(r"\d+\.\d\d", ratio_with_acting)
    # acting added to the serial limit lowers it, so ours stands higher against it
    assert abs(float(ratio_with_acting) - ours * (1 / sim + 1 / update + 1 / act)) <= 0.01
    assert float(ratio_with_acting) > float(ratio)
    # the ratio over both rounds is a weighted mean of the single rounds', so they bracket it
    lowest, highest = (float(v) for v in rounds.split("-"))
    assert lowest - 0.005 <= float(ratio) <= highest + 0.005 and lowest <= highest
    assert row.split()[-1] == resolved_precision("auto", "cpu")  # the recipe's products on Bounce


def test_learning_vs_peers_trains_ours_then_reads_a_finished_run(tmp_path):
    from helpers import TINY

    tiny = [o for o in TINY if not o.startswith(("total_frames=", "env.num_envs=", "torch_threads="))]
    common = [sys.executable, str(BENCHMARKS / "learning_vs_peers.py"), "--frames", "512", "--threads", "1"]
    common += ["--marks", "256,512", "--window", "512", "--eval-episodes", "4", "--curve-episodes", "2"]
    trained = subprocess.run(
        [*common, "--exp", "bounce_ppo", "--num-envs", "8", "--out", str(tmp_path), *tiny],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert trained.returncode == 0, trained.stderr[-2000:]
    assert (tmp_path / "ours" / "train.csv").is_file()
    again = subprocess.run(
        [*common, "--ours-run", str(tmp_path / "ours"), "--out", str(tmp_path / "again")],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert again.returncode == 0, again.stderr[-2000:]
    rows = [line for line in again.stdout.splitlines() if line.startswith("ours")]
    assert rows == [line for line in trained.stdout.splitlines() if line.startswith("ours")]
    assert "bounce_ppo, 8 worlds, seed 0" in again.stdout  # the run's own config
    # the final policy's deterministic episodes, with both actions (the same seed both times)
    assert "final policy, 4 deterministic episodes: bounces_per_10s" in again.stdout
    final = rows[-1].split()[1:]
    assert len(final) == 2 and all(float(v) >= 0 for v in final)
    refused = subprocess.run(
        [*common, "--ours-run", str(tmp_path / "ours"), "agent.lr=1e-3"], capture_output=True, text=True
    )
    assert refused.returncode == 2 and "--ours-run reads a finished run" in refused.stderr


@pytest.mark.parametrize("physics", [True, False])
def test_env_breakdown_accounts_for_the_whole_step(physics):
    command = [sys.executable, str(BENCHMARKS / "env_throughput.py"), "--breakdown"]
    command += ["--tasks", "bounce", "--num-envs", "8", "--threads", "1", "--steps", "40", "--rounds", "1"]
    done = subprocess.run(command + ([] if physics else ["--no-physics"]), capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    row = next(line for line in done.stdout.splitlines() if line.startswith("bounce"))
    resets, *parts, outside, share, budget, floor = (float(v.replace(",", "")) for v in row.split()[3:])
    physics_us, _, ours_reset, own_transforms, kept_transforms, torchrl = parts
    assert len(parts) == 6 and all(p >= 0 for p in parts)
    assert abs(outside - sum(parts[1:])) <= 3  # rounding of the printed parts
    assert own_transforms > 0 and kept_transforms > 0  # both groups are timed, each its own
    assert abs(floor - (kept_transforms + torchrl)) <= 2 and abs(budget - physics_us / 9) <= 1
    if physics:
        assert physics_us > 0 and 0.0 <= resets <= 1.0 and 0.0 < share < 1.0
    else:  # frozen worlds: nothing falls, nothing resets, the Python parts are all there is
        assert resets == 0.0 and ours_reset == 0.0 and share < 0.05


def test_the_layer_norm_peer_runs_rsl_rl_with_our_encoder_layer_norms():
    """``rsl_rl_ln`` (``benchmarks/peers.py``): rsl_rl's actor and critic MLPs with a LayerNorm
    after every hidden layer, as our encoder has; needs the optional ``.[bench]`` extra."""
    pytest.importorskip("rsl_rl")
    import torch
    from helpers import compose_cfg

    sys.path.insert(0, str(BENCHMARKS))
    from peers import rsl_rl_runner

    cfg = compose_cfg(["+exp=bounce_ppo", "+profile=cpu", "env.num_envs=4", "agent.rollout_len=4"])
    for layer_norm, sizes in ((False, [[], []]), (True, [[1024, 512, 256], [256, 128]])):  # actor, critic
        runner, env = rsl_rl_runner(cfg, layer_norm=layer_norm)
        norms = [
            [m.normalized_shape[0] for m in net.mlp if isinstance(m, torch.nn.LayerNorm)]
            for net in (runner.alg.actor, runner.alg.critic)
        ]
        assert norms == sizes
        runner.learn(1)  # one rollout and update run through the changed networks
        env.envs.close()
