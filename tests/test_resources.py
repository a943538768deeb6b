"""The resolver finds assets/ and conf/, and the robot files come from gymnasium-robotics."""

import pytest
from omegaconf import OmegaConf

from roto_trl import TASKS, make_env
from roto_trl.envs.scene import robot_assets_dir
from roto_trl.utils.resources import resource_dir, resource_path


def test_assets_and_conf_resolve():
    assert resource_path("assets", "shadow_hand.xml").is_file()
    assert resource_dir("conf").is_dir()
    with pytest.raises(FileNotFoundError, match=r"no assets file 'missing\.xml'"):
        resource_path("assets", "missing.xml")
    with pytest.raises(ValueError, match="unknown resource kind"):
        resource_dir("weights")


def test_robot_files_are_read_from_the_installed_package_not_copied():
    assert (robot_assets_dir() / "hand" / "robot.xml").is_file()
    ours = {p.name for p in resource_dir("assets").iterdir()}
    assert not ours & {"robot.xml", "shared.xml", "shared_asset.xml"}


@pytest.mark.parametrize("task", sorted(TASKS))
def test_every_env_config_in_conf_builds(task):
    cfg = OmegaConf.load(resource_path("conf", f"env/{task}.yaml"))
    assert cfg.task == task
    env = make_env(cfg.task, 2, **OmegaConf.to_container(cfg.overrides))
    assert env.batch_size == (2,)
    env.close()
