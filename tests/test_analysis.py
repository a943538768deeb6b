"""Evaluation, the run report and the analysis commands on tiny trained runs; the KSG estimator."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import TINY, compose_cfg

from roto_trl import analyse, evaluate
from roto_trl.analysis.mutual_information import ksg_mutual_information, pca
from roto_trl.envs.factory import make_env
from roto_trl.train import train


def gaussian_pairs(d: int, rho: float, n: int = 5000, seed: int = 0):
    """x, y ``[n, d]``: each pair of columns is a standard bivariate Gaussian with correlation rho."""
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((n, d))
    return x, rho * x + np.sqrt(1 - rho**2) * rng.standard_normal((n, d))


@pytest.mark.parametrize("d", [1, 2])
def test_ksg_matches_the_closed_form_mi_of_correlated_gaussians(d):
    x, y = gaussian_pairs(d, 0.9)
    exact = -d / 2 * np.log(1 - 0.9**2)  # 0.830 nats per dimension
    assert abs(ksg_mutual_information(x, y, k=4) - exact) < 0.05


def test_ksg_reads_independent_variables_as_nearly_zero_and_checks_its_input():
    x, y = gaussian_pairs(2, 0.0, n=2000)
    assert abs(ksg_mutual_information(x, y, k=4)) < 0.03
    with pytest.raises(ValueError, match="same number of samples"):
        ksg_mutual_information(x, y[:10])


def test_pca_projects_on_the_axes_of_largest_variance():
    rng = np.random.default_rng(0)
    x = rng.standard_normal((1000, 3)) * np.array([10.0, 1.0, 0.1])
    scores, explained = pca(x, 2)
    assert scores.shape == (1000, 2)
    assert explained[0] > 0.98 and explained[0] + explained[1] > 0.9998  # the third axis holds 1e-4
    assert abs(np.corrcoef(scores[:, 0], x[:, 0])[0, 1]) > 0.999


def test_physical_metrics_per_task_by_hand():
    bounce = make_env("bounce", 1).base_env  # 600 steps at 60 Hz: 10 s episodes
    assert bounce.physical_metrics({"bounces": torch.tensor([2.0, 4.0])}) == {"bounces_per_10s": 3.0}
    short = make_env("baoding", 1, episode_steps=300).base_env  # 5 s: rates double
    assert short.physical_metrics({"rotations": torch.tensor([1.0, 0.0])}) == {"rotations_per_10s": 1.0}
    find = make_env("find", 1).base_env  # 5 s episodes; an unreached tolerance reads 5.0
    final = {
        "object_distance": torch.tensor([0.02, 0.04]),
        "find_time_3cm": torch.tensor([1.0, 5.0]),
        "find_time_1cm": torch.tensor([5.0, 5.0]),
        "find_time_0.05cm": torch.tensor([5.0, 5.0]),
    }
    metrics = find.physical_metrics(final)
    assert metrics["find_time_3cm"] == 3.0 and metrics["reached_3cm"] == 0.5
    assert metrics["reached_1cm"] == 0.0 and metrics["object_distance"] == pytest.approx(0.03)
    for env in (bounce, short, find):
        env.close()


@pytest.mark.parametrize("task", ["find", "bounce", "baoding"])
def test_state_names_label_every_state_element(task):
    env = make_env(task, 2)
    names = env.base_env.STATE_NAMES
    assert len(set(names)) == len(names) == env.observation_spec["state"].shape[-1]
    env.close()


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Tiny trained runs: two TFD seeds, one TR and one PPO run on Bounce, one PPO run on Find."""
    root = tmp_path_factory.mktemp("runs")
    made = {}
    bounce = [
        ("tfd0", "bounce_tfd", 0),
        ("tfd1", "bounce_tfd", 1),
        ("tr0", "bounce_tr", 0),
        ("ppo0", "bounce_ppo", 0),
    ]
    for name, exp, seed in bounce:
        # TINY's short episodes hold runs of 4; aux-memory reads every auxiliary step (aux.csv)
        short = ["ssl.seq_len=4", "logger.aux_minibatches=true"] if exp == "bounce_tfd" else []
        train(
            compose_cfg(
                [f"+exp={exp}", *TINY, *short, f"seed={seed}", "total_frames=512", f"run_dir={root / name}"]
            )
        )
        made[name] = root / name
    train(compose_cfg(["+exp=find_ppo", *TINY, f"run_dir={root / 'find'}"]))
    made["find"] = root / "find"
    return made


def table(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def test_training_ends_with_physical_metrics_and_a_report(runs):
    run = runs["tfd0"]
    result = json.loads((run / "eval.json").read_text())
    summary = json.loads((run / "summary.json").read_text())
    assert result["checkpoint"].endswith("best.pt") and result["episodes"] == 2
    assert set(result["physical"]) == {"bounces_per_10s"}
    # the best checkpoint replayed on the same worlds and seed gives its training evaluation
    assert result["return_mean"] == pytest.approx(summary["best_eval"]["return_mean"], abs=1e-6)
    index = (run / "index.md").read_text()
    assert "![evaluation](plots/eval.png)" in index and "bounces_per_10s" in index
    assert "| frames | 512 |" in index


def test_evaluate_is_deterministic_and_writes_video(runs, tmp_path):
    first = evaluate.main([f"run={runs['find']}", "episodes=3", "seed=7", f"out={tmp_path / 'a.json'}"])
    second = evaluate.main(
        [f"run={runs['find']}", "episodes=3", "seed=7", f"out={tmp_path / 'b.json'}", "video=true"]
    )
    a, b = json.loads(first.read_text()), json.loads(second.read_text())
    assert a["physical"] == b["physical"] and a["return_mean"] == b["return_mean"]
    assert {"find_time_3cm", "reached_3cm", "find_time_0.05cm", "reached_0.05cm"} <= set(a["physical"])
    assert Path(b["video"]).stat().st_size > 1000
    with pytest.raises(SystemExit, match=r"^evaluate: .*no camera 'roto:above'"):  # Baoding's only
        evaluate.main([f"run={runs['find']}", "episodes=1", "video=true", "camera=roto:above"])


def test_evaluate_can_act_with_the_policys_seeded_samples(runs, tmp_path):
    def result(name, *extra):
        args = [f"run={runs['ppo0']}", "episodes=4", "seed=3", f"out={tmp_path / name}", *extra]
        return json.loads(evaluate.main(args).read_text())

    mean_action = result("d.json")
    sampled, again = result("s1.json", "policy=stochastic"), result("s2.json", "policy=stochastic")
    gaussian_mean = result("g.json", "policy=gaussian_mean")
    # the default is the run's agent.deterministic_action: the mean of the applied action
    assert [r["policy"] for r in (mean_action, sampled, gaussian_mean)] == [
        "applied_mean",
        "stochastic",
        "gaussian_mean",
    ]
    assert sampled["return_mean"] == again["return_mean"]  # seeded
    assert sampled["return_mean"] != mean_action["return_mean"]  # a std-1 policy's samples differ
    # two controllers at std 1: the Find arm ends elsewhere (Bounce's ball drops either way)
    find = [f"run={runs['find']}", "episodes=2", "seed=3"]
    applied = json.loads(evaluate.main([*find, f"out={tmp_path / 'fa.json'}"]).read_text())
    gaussian = json.loads(
        evaluate.main([*find, f"out={tmp_path / 'fg.json'}", "policy=gaussian_mean"]).read_text()
    )
    assert applied["metrics"]["object_distance"] != gaussian["metrics"]["object_distance"]
    with pytest.raises(SystemExit, match=r"policy must be one of \['deterministic', 'applied_mean'"):
        evaluate.main([f"run={runs['ppo0']}", "policy=random"])


def test_evaluate_scales_the_sampled_policys_noise(runs, tmp_path):
    def result(name, *extra):
        args = [
            f"run={runs['ppo0']}",
            "episodes=4",
            "seed=3",
            f"out={tmp_path / name}",
            "policy=stochastic",
            *extra,
        ]
        return json.loads(evaluate.main(args).read_text())

    own, unit = result("s.json"), result("s1.json", "noise_scale=1")
    assert own["return_mean"] == unit["return_mean"] and "noise_scale" not in own
    half = result("h.json", "noise_scale=0.5")
    assert half["noise_scale"] == 0.5 and half["return_mean"] != own["return_mean"]
    # samples with a vanishing std are the Gaussian's mean, clipped by the env
    faint = result("f.json", "noise_scale=1e-9")
    mean = json.loads(
        evaluate.main(
            [
                f"run={runs['ppo0']}",
                "episodes=4",
                "seed=3",
                f"out={tmp_path / 'g.json'}",
                "policy=gaussian_mean",
            ]
        ).read_text()
    )
    assert faint["return_mean"] == pytest.approx(mean["return_mean"], rel=1e-4)
    with pytest.raises(SystemExit, match="noise_scale scales the samples of policy=stochastic"):
        evaluate.main([f"run={runs['ppo0']}", "noise_scale=0.5"])
    with pytest.raises(SystemExit, match="noise_scale must be a number > 0"):
        evaluate.main([f"run={runs['ppo0']}", "policy=stochastic", "noise_scale=0"])


def test_evaluate_rejects_missing_and_foreign_checkpoints(runs, tmp_path):
    with pytest.raises(SystemExit, match=r"no config\.yaml"):
        evaluate.main([f"run={tmp_path}"])
    with pytest.raises(SystemExit, match="no checkpoint at"):
        evaluate.main([f"run={runs['ppo0']}", f"checkpoint={tmp_path / 'none.pt'}"])
    foreign = runs["find"] / "checkpoints" / "best.pt"
    with pytest.raises(SystemExit, match=r"trained on 'find' but run .* is 'bounce'"):
        evaluate.main([f"run={runs['ppo0']}", f"checkpoint={foreign}"])
    state = torch.load(runs["ppo0"] / "checkpoints" / "best.pt", weights_only=False)
    state["config"]["env"]["obs_keys"] = ["prop"]  # a proprioception-only agent's checkpoint
    torch.save(state, tmp_path / "prop.pt")
    with pytest.raises(SystemExit, match=r"sees obs_keys=\['prop'\], last_action=True but run"):
        evaluate.main([f"run={runs['ppo0']}", f"checkpoint={tmp_path / 'prop.pt'}"])
    state["config"]["env"]["obs_keys"] = ["prop", "tactile"]
    state["agent"]["encoder.net.0.weight"] = state["agent"]["encoder.net.0.weight"][:, :10]  # other sizes
    torch.save(state, tmp_path / "sizes.pt")
    with pytest.raises(SystemExit, match="does not fit this env's observations"):
        evaluate.main([f"run={runs['ppo0']}", f"checkpoint={tmp_path / 'sizes.pt'}"])
    with pytest.raises(SystemExit, match=r"give run=\.\.\."):
        evaluate.main([])


def test_curves_average_seeds_and_chart_physical_metrics(runs, tmp_path):
    written = analyse.main(
        ["curves", str(runs["tfd0"].parent / "*[do]0"), str(runs["tfd1"]), "--out", str(tmp_path)]
    )
    assert all(p.stat().st_size > 0 for p in written)
    curves = table(tmp_path / "curves.csv")
    tfd = [r for r in curves if r["exp_name"] == "bounce_tfd"]
    assert [int(r["frames"]) for r in tfd] == [0, 256, 512] and {r["seeds"] for r in tfd} == {"2"}
    assert {r["exp_name"] for r in curves} == {"bounce_tfd", "bounce_ppo"}
    physical = table(tmp_path / "physical.csv")
    assert {(r["exp_name"], r["metric"]) for r in physical} == {
        (e, m) for e in ("bounce_tfd", "bounce_ppo") for m in ("return", "bounces_per_10s")
    }
    assert all(float(r["max"]) >= float(r["mean"]) for r in physical)


def test_mi_latent_tactile_and_aux_memory_write_figures_and_numbers(runs, tmp_path):
    mi = analyse.main(
        [
            "mi",
            str(runs["tfd0"]),
            str(runs["ppo0"]),
            "--worlds",
            "4",
            "--samples",
            "120",
            "--pca",
            "5",
            "--out",
            str(tmp_path),
        ]
    )
    rows = table(tmp_path / "mi.csv")
    assert len(rows) == 2 * (1 + 14)  # joint + one per Bounce state element, for both agents
    assert all(np.isfinite(float(r["mi_nats"])) for r in rows)
    assert [r["state"] for r in rows[:3]] == ["joint", "joint", "ball_x"]
    latent = analyse.main(["latent", str(runs["tfd0"]), "--out", str(tmp_path)])
    assert len(table(latent[1])) == 40 and {"pc1", "pc2", "contacts"} <= set(table(latent[1])[0])
    tactile = analyse.main(["tactile", str(runs["tfd0"]), "--steps", "30", "--out", str(tmp_path)])
    cells = table(tactile[1])
    assert len(cells) == 29 * 17  # one step ahead over 30 steps, 17 Shadow Hand sensors
    assert all(0.0 <= float(r["predicted"]) <= 1.0 for r in cells)
    metrics = {r["metric"] for r in table(tactile[3])}
    assert {"tpr_h1", "fpr_h3", "precision_h2"} <= metrics
    # a TR run beside it: reconstruction of every step's own reading, metrics without horizons
    both = analyse.main(
        ["tactile", str(runs["tr0"]), str(runs["tfd0"]), "--steps", "30", "--out", str(tmp_path)]
    )
    assert len(table(both[1])) == 30 * 17 and len(table(both[5])) == 29 * 17
    assert {"tpr", "precision"} <= {r["metric"] for r in table(both[3])}
    memory = analyse.main(["aux-memory", str(runs["tfd0"]), str(runs["tfd1"]), "--out", str(tmp_path)])
    assert len(table(memory[1])) == 2 * len(table(runs["tfd0"] / "aux.csv"))
    minutes = analyse.main(
        ["curves", str(runs["tfd0"]), "--x", "minutes", "--no-physical", "--out", str(tmp_path)]
    )
    at = [float(r["minutes"]) for r in table(minutes[1])]
    assert len(at) == 3 and at[0] == 0.0 and at[1] < at[2]  # eval times rise from the start
    for path in [*mi, *latent, *tactile, *memory, *minutes]:
        assert path.stat().st_size > 0


def test_analyse_rejects_bad_inputs_with_one_line(runs, tmp_path):
    with pytest.raises(SystemExit, match="no run directories match"):
        analyse.main(["curves", str(tmp_path / "nothing*")])
    with pytest.raises(SystemExit, match="mix \\['bounce', 'find'\\]"):
        analyse.main(["mi", str(runs["ppo0"]), str(runs["find"]), "--out", str(tmp_path)])
    with pytest.raises(SystemExit, match="needs a TR or TFD run"):
        analyse.main(["tactile", str(runs["ppo0"]), "--out", str(tmp_path)])


def test_training_evaluations_log_the_tables_numbers(runs, tmp_path):
    """Every evaluation during training logs the physical metrics the results table reads."""
    find = table(runs["find"] / "eval.csv")
    assert {"reached_3cm", "reached_1cm", "reached_0.05cm", "find_time_1cm"} <= set(find[0])
    assert all(0.0 <= float(row["reached_1cm"]) <= 1.0 for row in find)
    last = [table(runs[name] / "eval.csv")[-1] for name in ("tfd0", "tfd1")]
    analyse.main(["table", str(runs["tfd0"]), str(runs["tfd1"]), str(runs["find"]), "--out", str(tmp_path)])
    rows = {(r["exp_name"], r["metric"]): r for r in table(tmp_path / "table.csv")}
    bounces = rows[("bounce_tfd", "bounces_per_10s")]
    per_run = [float(row["bounces_per_10s"]) for row in last]
    assert int(bounces["seeds"]) == 2 and float(bounces["frames"]) == 512
    assert float(bounces["mean"]) == pytest.approx(np.mean(per_run))
    assert float(bounces["max"]) == pytest.approx(max(per_run))
    assert {m for e, m in rows if e == "find_ppo"} == {
        "return",
        "find_time_3cm_s",
        "reached_3cm",
        "find_time_1cm_s",
        "reached_1cm",
        "find_time_0.05cm_s",
        "reached_0.05cm",
    }
