"""The typed config: one schema for every key, profiles on top of experiments in any order, saved
runs loaded over today's defaults, retired options refused, misspelt keys caught."""

import json
from pathlib import Path

import pytest
import torch
from helpers import compose_cfg
from omegaconf import OmegaConf

from roto_trl.analysis.checkpoint_eval import evaluate_run
from roto_trl.analysis.runs import settings
from roto_trl.config import (
    RETIRED_TAG,
    AgentConfig,
    check_run_name,
    compose_train,
    hydra_overrides,
    plain,
    run_config,
    schema,
    typed_config,
)
from roto_trl.train import train
from roto_trl.trainers.checkpoint import load_checkpoint, save_checkpoint
from roto_trl.utils.resources import resource_dir

FIXTURE = Path(__file__).parent / "fixtures" / "config_before_typed_schema.yaml"
EXPS = sorted(p.stem for p in (resource_dir("conf") / "exp").glob("*.yaml"))
PROFILES = sorted(p.stem for p in (resource_dir("conf") / "profile").glob("*.yaml"))


def test_the_agent_has_at_most_25_keys_and_ppo_yaml_sets_each_once():
    keys = list(AgentConfig.__dataclass_fields__)
    assert len(keys) <= 25
    shipped = OmegaConf.load(resource_dir("conf") / "agent" / "ppo.yaml")
    assert list(shipped) == keys  # the yaml lists every key, in the schema's order
    assert plain(typed_config({"agent": shipped}))["agent"] == OmegaConf.to_container(shipped)


@pytest.mark.parametrize("exp", EXPS)
def test_a_profile_composes_on_top_of_the_experiment_in_either_order(exp):
    for profile in PROFILES:
        first = plain(typed_config(compose_train([f"+exp={exp}", f"+profile={profile}"])))
        second = plain(typed_config(compose_train([f"+profile={profile}", f"+exp={exp}"])))
        assert first == second, profile
    cpu = compose_train(["+profile=cpu", f"+exp={exp}"])
    assert cpu.agent.minibatches == 8 and cpu.env.num_envs == 256  # the profile's, not the exp's
    quick = compose_train(["+profile=quickstart", f"+exp={exp}"])
    assert (quick.agent.lr, quick.agent.epochs, quick.agent.minibatches) == (3e-4, 4, 4)


def test_plus_exp_and_plus_profile_name_the_groups_the_defaults_list_orders():
    args = ["+profile=cpu", "agent.lr=1", "+exp=find_ppo", "+env.overrides.x=1"]
    assert hydra_overrides(args) == ["profile=cpu", "agent.lr=1", "exp=find_ppo", "+env.overrides.x=1"]


def test_a_misspelt_key_is_refused_even_when_added_with_plus():
    with pytest.raises(ValueError, match=r"^agent\.lrr is not a config key; did you mean agent\.lr\?"):
        compose_cfg(["+exp=find_ppo", "+agent.lrr=1e-3"])
    with pytest.raises(ValueError, match=r"^evaluation is not a config key"):
        compose_cfg(["+exp=find_ppo", "+evaluation.num_envs=3"])


def test_types_choices_and_ranges_are_one_line_errors_naming_the_key():
    for override, message in (
        ("agent.epochs=1.5", r"^agent\.epochs must be an integer, got 1\.5$"),
        ("progress=maybe", r"^progress must be true or false, got maybe$"),
        ("agent.lr=0", r"^agent\.lr must be > 0, got 0\.0$"),
        ("agent.gamma=1.5", r"^agent\.gamma must be <= 1, got 1\.5$"),
        ("ssl.name=byol", r"^ssl\.name must be one of none, tr, fr, fd, tfd, got byol$"),
        ("seed=-1", r"^seed must be >= 0, got -1$"),
        ("agent.lr=nan", r"^agent\.lr must be > 0, got nan$"),
    ):
        with pytest.raises(ValueError, match=message):
            compose_cfg(["+exp=find_ppo", override])


def test_a_retired_option_is_refused_with_its_tag_and_dropped_where_it_changed_nothing():
    with pytest.raises(ValueError, match=rf"agent\.policy_ema_decay=0\.9: .* git checkout {RETIRED_TAG}"):
        typed_config({"agent": {"policy_ema_decay": 0.9}})
    with pytest.raises(ValueError, match=rf"agent\.std_ceiling=0\.3: .* git checkout {RETIRED_TAG}"):
        typed_config({"agent": {"std_ceiling": 0.3, "std_ceiling_frames": [500000, 1500000]}})
    with pytest.raises(ValueError, match=r"agent\.adam_eps=1e-05: this option was retired"):
        typed_config({"agent": {"adam_eps": 1e-5}})
    off = {"policy_ema_decay": 0.0, "adam_eps": 1e-8, "fused_adam": False}
    off |= {"adam_betas": [0.9, 0.999], "gae_horizon": None}
    assert plain(typed_config({"agent": off}))["agent"] == plain(schema())["agent"]
    # the window of a run without a ceiling changed nothing either
    no_ceiling = typed_config({"agent": {"std_ceiling": None, "std_ceiling_frames": [0, 10]}})
    assert plain(no_ceiling)["agent"] == plain(schema())["agent"]


def test_a_config_saved_before_the_schema_loads_as_today_with_the_same_values():
    old = OmegaConf.to_container(OmegaConf.load(FIXTURE))
    new = plain(run_config(FIXTURE))
    assert "cpu_recipe" in old["env"] and "cpu_recipe" not in new["env"]
    retired = {"gae_horizon", "action_log_prob", "mean_bound", "mean_bound_coeff", "policy_ema_decay"}
    assert retired <= set(old["agent"]) and not retired & set(new["agent"])
    for key, value in new["agent"].items():  # every kept key as it was saved
        assert value == old["agent"][key] or (value, old["agent"][key]) == (0.0, None), key
    assert new["ssl"] == {**new["ssl"], **old["ssl"]} and new["env"]["overrides"] == old["env"]["overrides"]


def test_a_run_directory_saved_before_the_schema_resumes_and_evaluates(tmp_path):
    """A run of today's code given the old config.yaml (the fixture: bounce_fd with the CPU recipe,
    saved with every option the schema retired at its off value) in the run directory and in its
    checkpoint, as the commit before the schema wrote them: it evaluates and resumes."""
    run = tmp_path / "run"
    cfg = run_config(FIXTURE)
    cfg.run_dir, cfg.total_frames, cfg.progress = str(run), 512, False  # one iteration of 16 x 32
    train(cfg)
    old = OmegaConf.load(FIXTURE)
    old.run_dir, old.total_frames = str(run), 512
    OmegaConf.save(old, run / "config.yaml")
    for name in ("latest.pt", "best.pt"):
        state = torch.load(run / "checkpoints" / name, weights_only=False)
        state["config"] = OmegaConf.to_container(old)
        save_checkpoint(run / "checkpoints" / name, state)
    assert load_checkpoint(run)["config"].agent.minibatches == 8
    result = json.loads(evaluate_run(run, "latest", episodes=2).read_text())
    assert result["trained_frames"] == 512
    train(compose_cfg([f"resume={run}", "total_frames=1024"]), ["total_frames=1024"])
    assert load_checkpoint(run)["frames"] == 1024
    assert OmegaConf.load(run / "config.yaml").total_frames == 1024


def test_an_override_that_changes_what_an_experiment_trains_needs_a_name_of_its_own(tmp_path):
    for overrides in (["+exp=bounce_ppo", "ssl=fd"], ["+exp=bounce_ppo", "env=find"], ["ssl=tr"]):
        with pytest.raises(ValueError, match=r"changes what the run trains; name it with exp_name=<name>"):
            train(compose_cfg([*overrides, f"run_dir={tmp_path / 'x'}"]), overrides)
        check_run_name([*overrides, "exp_name=mine"])  # named: accepted
    assert not (tmp_path / "x").exists()
    check_run_name(["env=bounce", "agent.lr=1e-3"])  # no exp: the default name follows the task
    check_run_name(["+exp=bounce_fd", "ssl.coeff=0.5", "ssl.memory_rollouts=3"])  # tuning, not identity


def test_frame_counts_are_written_as_a_user_would_and_the_cpu_profile_sets_each_tasks_budget():
    for written in ("2M", "2_000_000", "2e6", "2000000"):
        assert compose_cfg(["+exp=bounce_fd", f"total_frames={written}"]).total_frames == 2_000_000
    for bad in ("2.5", "0", "lots"):
        with pytest.raises(ValueError, match=r"^total_frames must be a positive whole number of frames"):
            compose_cfg(["+exp=bounce_fd", f"total_frames={bad}"])
    budgets = {exp: compose_cfg([f"+exp={exp}", "+profile=cpu"]).total_frames for exp in EXPS}
    assert {e: f for e, f in budgets.items() if not e.startswith("baoding")} == dict.fromkeys(
        [e for e in EXPS if not e.startswith("baoding")], 2_000_000
    )
    assert {budgets[e] for e in EXPS if e.startswith("baoding")} == {10_000_000}
    assert compose_cfg(["+exp=bounce_fd", "+profile=cpu", "total_frames=3M"]).total_frames == 3_000_000


def test_every_variant_of_a_task_gets_one_recipe():
    """Under +profile=cpu the variants of a task differ only in what Table A4 tunes per variant
    (R, le, lr, c_ent, the SSL objective and its values) and in what they observe."""
    per_variant = ("agent.rollout_len", "agent.epochs", "agent.lr", "agent.entropy_coeff")
    identity = ("exp_name", "env.obs_keys", "env.last_action")
    for task in ("find", "bounce", "baoding"):
        recipes = {}
        for exp in (e for e in EXPS if e.startswith(task)):
            flat = settings(plain(typed_config(compose_train([f"+exp={exp}", "+profile=cpu"]))))
            recipes[exp] = {
                k: v
                for k, v in flat.items()
                if k not in (*per_variant, *identity) and not k.startswith("ssl.")
            }
        first = next(iter(recipes.values()))
        assert all(recipe == first for recipe in recipes.values()), task
