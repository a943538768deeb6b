"""Compile a RoTO scene: our XML from ``assets/`` plus robot files from gymnasium-robotics.

The robot models (the OpenAI Shadow Hand, the kitchen Franka) are read at run time from the
installed ``gymnasium-robotics`` wheel, located without importing it (its ``__init__`` registers
dozens of environments and imports their dependencies). Nothing is copied into our repository.
Every file is handed to MuJoCo through an in-memory asset dictionary keyed by file name, so our
scene files can ``<include file="robot.xml"/>`` as if the robot's files lay beside them.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable
from functools import cache
from pathlib import Path

import mujoco

from roto_trl.utils.resources import resource_dir, resource_path

CONTROL_HZ = 60
CONTROL_DT = 1.0 / CONTROL_HZ

# Robot folders inside gymnasium_robotics/envs/assets. Each file is keyed by its path relative to
# the folder listed, which is how the package's own XML names it (``<include file="robot.xml"/>``,
# ``franka_assets/chain.xml``; mesh paths are relative to the ``meshdir`` the files set).
_ROBOT_DIRS = {"hand": ("hand", "stls/hand"), "franka": ("kitchen_franka/franka_assets",)}
_ROBOT_KEY_PREFIX = {"hand": "", "franka": "franka_assets/"}
# Name prefix of the robot's bodies in its files.
ROBOT_PREFIX = {"hand": "robot0:", "franka": "panda0_"}


@cache
def robot_assets_dir() -> Path:
    """The ``envs/assets`` folder of the installed gymnasium-robotics package."""
    spec = importlib.util.find_spec("gymnasium_robotics")
    if spec is None or not spec.submodule_search_locations:
        raise ModuleNotFoundError(
            "gymnasium-robotics is not installed; it provides the robot models "
            "(pip install 'gymnasium-robotics>=1.4')"
        )
    path = Path(next(iter(spec.submodule_search_locations))) / "envs" / "assets"
    if not path.is_dir():
        raise FileNotFoundError(f"gymnasium-robotics at {path.parent.parent} ships no envs/assets")
    return path


@cache
def _robot_files(robot: str) -> dict[str, bytes]:
    files: dict[str, bytes] = {}
    for sub in _ROBOT_DIRS[robot]:
        root = robot_assets_dir() / sub
        for path in root.rglob("*"):
            if path.suffix.lower() in (".xml", ".stl", ".png"):
                files[_ROBOT_KEY_PREFIX[robot] + path.relative_to(root).as_posix()] = path.read_bytes()
    return files


def load_scene(
    scene_file: str,
    robot: str,
    substeps: int,
    edit: Callable[[mujoco.MjSpec], None] | None = None,
) -> mujoco.MjModel:
    """Compile ``assets/<scene_file>`` with the robot's files, at ``substeps`` per 60 Hz step.

    ``edit(spec)``, when given, changes the parsed spec before it is compiled: the way to add
    bodies inside the robot's own bodies, which our XML cannot reach (Find's finger pads).

    The robot's links are gravity-compensated (``gravcomp = 1``): Isaac Lab's robot configs, on
    which the paper ran, disable gravity on the robot links, and without it the Shadow Hand's
    weak wrist servos (kp = 5) sag about 5 degrees under the hand's weight.

    Returns:
        The compiled model with ``opt.timestep = 1 / (60 * substeps)``.
    """
    if int(substeps) < 1:
        raise ValueError(f"substeps must be a positive integer, got {substeps}")
    files = dict(_robot_files(robot))
    xml_files = {p.name: p.read_bytes() for p in resource_dir("assets").glob("*.xml")}
    xml_files.update({k: v for k, v in files.items() if k.endswith(".xml")})
    meshes = {k: v for k, v in files.items() if not k.endswith(".xml")}
    xml = resource_path("assets", scene_file).read_text()
    spec = mujoco.MjSpec.from_string(xml, include=xml_files, assets=meshes)
    for body in spec.bodies:
        if body.name.startswith(ROBOT_PREFIX[robot]):
            body.gravcomp = 1.0
    if edit is not None:
        edit(spec)
    model = spec.compile()
    model.opt.timestep = CONTROL_DT / int(substeps)
    return model
