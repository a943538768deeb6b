"""Find: locate, by touch, a fixed sphere somewhere on a 20 x 20 cm plate with the Franka.

The sphere (``SPHERE_RADIUS``) is a mocap body: touching it never moves it. At each reset it is
placed uniformly on the plate and the arm's joints start within +-``joint_reset_deg`` of
``READY_POSE``, the gripper open. Two thin pads on the inner finger surfaces are the tactile
sensors; by collision groups (``assets/find.xml``) they feel only the sphere and each other.
Reward (the paper's Table A2): ``dist`` = 1 - tanh(d / 0.1), d the distance from the end-effector
frame (``TCP_SITE``: the tool centre point between the fingertips, 1 cm short of their ends, as
Isaac Lab's Franka TCP) to the sphere centre. With the open fingers around the sphere the frame
can reach its centre without the fingertips touching the plate, so every tolerance is reachable.
No termination; 300 steps (5 s). The joint targets are smoothed, ``action_ema`` = 0.3 by default
(the authors' release; the paper is silent).

Metrics in every step's output: ``object_distance`` [N, 1] (d, metres) and ``find_time``
[N, len(tolerances)]: the time in seconds at which d first fell below each tolerance this
episode, or the episode's duration (5.0) while it has not (so that episode means stay finite and
an agent that never finds reads as slow as possible).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np
import torch
from torchrl.data import Unbounded

from roto_trl.envs.batched_mujoco import PhysicsReading
from roto_trl.envs.robot_env import RobotTaskEnv, TaskConfig, sensor_slice
from roto_trl.envs.scene import CONTROL_DT

SCENE = "find.xml"
N_FRANKA_JOINTS = 9  # 7 arm joints, 2 finger slides
N_ARM_JOINTS = 7
# The gripper pointing straight down, fingers opening along y, its end-effector frame 8 cm above
# the plate's centre (0.5, 0, 0.01), the fingertips 7 cm (radians; metres for the open fingers).
# Solved once by damped least squares on this scene's kinematics; tests/test_find.py checks where
# it points.
READY_POSE = {
    "panda0_joint1": 0.0, "panda0_joint2": 0.199, "panda0_joint3": 0.0, "panda0_joint4": -2.401,
    "panda0_joint5": 0.0, "panda0_joint6": 1.03, "panda0_joint7": 0.0,
    "panda0_finger_joint1": 0.04, "panda0_finger_joint2": 0.04,
}  # fmt: skip
PLATE_CENTRE = (0.5, 0.0)
PLATE_HALF = 0.1  # the plate is 20 x 20 cm
PLATE_TOP = 0.01
SPHERE_RADIUS = 0.025
HEADLINE_TOLERANCE = 0.03  # m: reached_3cm, the headline metric (FindEnv.HEADLINE_METRIC)
SPHERE_LIFT = 0.0005  # the sphere hovers 0.5 mm above the plate so the two never touch
DIST_REWARD_LENGTH = 0.1
REWARD_SCALES = {"dist": 1.0}
FINGER_PADS = ("left_pad", "right_pad")
# Pads: 1.6 x 50 mm x 2 mm plates on the inner surface of each finger, from 4 to 9 cm along it.
PAD_HALF_SIZE = (0.008, 0.001, 0.025)
PAD_POS = {"panda0_leftfinger": (0.0, -0.002, 0.065), "panda0_rightfinger": (0.0, 0.002, 0.065)}
# The end-effector frame, a site on the package's last link: on the gripper axis 1 cm short of the
# fingertip ends (finger bodies at 0.1654, their collision capsules end 0.0875 + 0.007 further:
# 0.2599) and turned like the hand (z along the fingers, the fingers opening along its y axis).
TCP_SITE = "roto:tcp"
TCP_BODY = "panda0_link7"
TCP_POS = (0.0, 0.0, 0.25)
TCP_QUAT = (0.9238795, 0.0, 0.0, -0.3826834)
# the privileged state (never an agent input; the mutual-information analysis reads it), in order
STATE_NAMES = ("sphere_x", "sphere_y", "sphere_z", "ee_x", "ee_y", "ee_z")


def first_times(
    dist: torch.Tensor, times: torch.Tensor, elapsed: torch.Tensor, tolerances: torch.Tensor
) -> torch.Tensor:
    """Update the first time d fell below each tolerance.

    Args:
        dist: ``[N]`` distance this step (m).
        times: ``[N, T]`` first times so far; ``inf`` where not reached yet.
        elapsed: ``[N]`` seconds since the episode started, this step included.
        tolerances: ``[T]`` metres.

    Returns:
        ``[N, T]`` updated first times (``inf`` where still not reached).
    """
    reached_now = (dist.unsqueeze(-1) < tolerances) & torch.isinf(times)
    return torch.where(reached_now, elapsed.unsqueeze(-1).to(times.dtype), times)


@dataclass
class FindConfig(TaskConfig):
    """Settings of Find (see ``TaskConfig`` for the common ones).

    Find's defaults differ from ``TaskConfig``'s in ``episode_steps`` (300), ``history`` (16) and
    ``action_ema`` (0.3: the authors' release smooths Find's joint targets, not the Shadow tasks').

    Attributes:
        joint_reset_deg: arm joints start uniformly within +- this many degrees of the ready pose.
        tolerances: distances (m) whose first-reach times are reported in ``find_time``; the
            paper prints 3 cm, 1 cm and 0.05 cm (its released code used 0.5 cm).
    """

    episode_steps: int = 300
    history: int = 16
    action_ema: float = 0.3
    joint_reset_deg: float = 7.0
    tolerances: tuple[float, ...] = (0.03, 0.01, 0.0005)
    reward_scales: dict[str, float] = field(default_factory=lambda: dict(REWARD_SCALES))

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0.0 <= self.joint_reset_deg <= 45.0:
            raise ValueError(f"joint_reset_deg must be in [0, 45], got {self.joint_reset_deg}")
        self.tolerances = tuple(float(t) for t in self.tolerances)
        if not self.tolerances or min(self.tolerances) <= 0.0:
            raise ValueError(f"tolerances must be a non-empty list of distances > 0 m, got {self.tolerances}")
        if HEADLINE_TOLERANCE not in self.tolerances:
            raise ValueError(
                f"tolerances {list(self.tolerances)} must include {HEADLINE_TOLERANCE} (3 cm: the "
                "results table's metric, which also picks the best checkpoint); add it"
            )


def add_tcp_site(spec: mujoco.MjSpec) -> None:
    """Add the end-effector frame ``TCP_SITE`` to the package's last link in the scene's spec.

    In site group 4, which renders hide by default: it marks a point, it is not a part.
    """
    spec.body(TCP_BODY).add_site(name=TCP_SITE, pos=TCP_POS, quat=TCP_QUAT, size=(0.005, 0, 0), group=4)


def add_finger_pads(spec: mujoco.MjSpec) -> None:
    """Add the two sensor pads, bodies inside the package's finger bodies, to the scene's spec."""
    for name, (finger, pos) in zip(FINGER_PADS, PAD_POS.items(), strict=True):
        pad = spec.body(finger).add_body(name=f"roto:{name}", pos=pos)
        pad.add_geom(
            name=f"roto:{name}",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=PAD_HALF_SIZE,
            mass=0.001,
            contype=2,
            conaffinity=2,
            group=0,
            material="roto:pad",
        )


class FindEnv(RobotTaskEnv):
    """Find on the Franka. Metrics: ``object_distance`` (m) and ``find_time`` (s, per tolerance)."""

    SCENE = SCENE
    ROBOT = "franka"
    N_JOINTS = N_FRANKA_JOINTS
    SENSORS = FINGER_PADS
    DEFAULT_POSE = READY_POSE
    VEL_SCALE = 0.33
    PROP_EXTRA = ("ee_pos", "ee_quat", "gripper_width")
    METRICS = ("object_distance", "find_time")
    HEADLINE_METRIC = "reached_3cm"  # fraction of episodes that came within 3 cm
    STATE_NAMES = STATE_NAMES
    CONFIG = FindConfig

    def __init__(self, num_envs: int, config: FindConfig | None = None, **kwargs):
        super().__init__(num_envs, config, **kwargs)
        m = self.mj_model
        if m.njnt != N_FRANKA_JOINTS or m.nu != N_FRANKA_JOINTS or m.nmocap != 1:
            raise RuntimeError(f"{SCENE}: expected 9 joints, 9 actuators and one mocap sphere")
        self._ee_pos = sensor_slice(m, "ee:pos")
        self._ee_quat = sensor_slice(m, "ee:quat")
        self.tolerances = torch.tensor(self.config.tolerances, dtype=torch.float64)
        self._first = torch.full((self.num_envs, len(self.tolerances)), float("inf"), dtype=torch.float64)
        self._dist = torch.zeros(self.num_envs, dtype=torch.float64)

    def metric_columns(self) -> list[tuple[str, int, str]]:
        """``object_distance``, then ``find_time_<tolerance in cm>cm`` per tolerance."""
        times = [("find_time", i, f"find_time_{100 * t:g}cm") for i, t in enumerate(self.config.tolerances)]
        return [("object_distance", 0, "object_distance"), *times]

    def physical_metrics(self, final: dict[str, torch.Tensor]) -> dict[str, float]:
        """Find's physical metrics from each episode's final values (``name -> [E]``).

        Returns ``object_distance`` (m, at the episode's end) and, per tolerance, ``find_time_<tol>``
        (s, mean over episodes; an episode that never reached it counts the full 5 s) and
        ``reached_<tol>`` (the fraction of episodes that got within it before the last step).
        """
        out = {"object_distance": float(final["object_distance"].double().mean())}
        for _, _, name in self.metric_columns()[1:]:
            times = final[name].double()
            out[name] = float(times.mean())
            out["reached_" + name.removeprefix("find_time_")] = float(
                (times < self.episode_seconds).double().mean()
            )
        return out

    def _edit_spec(self, spec: mujoco.MjSpec) -> None:
        add_finger_pads(spec)
        add_tcp_site(spec)

    def _make_obs_spec(self) -> dict:
        n = self.num_envs
        return {
            **self._robot_obs_spec(),
            "ee_pos": Unbounded(shape=(n, 3), dtype=torch.float32),
            "ee_quat": Unbounded(shape=(n, 4), dtype=torch.float32),
            "gripper_width": Unbounded(shape=(n, 1), dtype=torch.float32),
            "state": Unbounded(shape=(n, len(self.STATE_NAMES)), dtype=torch.float32),
            "object_distance": Unbounded(shape=(n, 1), dtype=torch.float32),
            "find_time": Unbounded(shape=(n, len(self.config.tolerances)), dtype=torch.float32),
        }

    def _sample_initial_state(self, idx: np.ndarray):
        n = len(idx)
        qpos = np.tile(self._default_ctrl, (n, 1))  # actuator i drives joint i
        noise = np.deg2rad(self.config.joint_reset_deg)
        qpos[:, :N_ARM_JOINTS] += self.rng.uniform(-noise, noise, size=(n, N_ARM_JOINTS))
        low, high = self.joint_low.double().numpy(), self.joint_high.double().numpy()
        qpos = np.clip(qpos, low, high)
        xy = np.asarray(PLATE_CENTRE) + self.rng.uniform(-PLATE_HALF, PLATE_HALF, size=(n, 2))
        self._mocap_pos[idx, 0, :2] = xy
        self._mocap_pos[idx, 0, 2] = PLATE_TOP + SPHERE_RADIUS + SPHERE_LIFT
        return qpos, np.zeros((n, self.mj_model.nv)), self._ctrl_for_state(idx, qpos)

    def _on_reset_mask(self, idx: np.ndarray) -> None:
        self._first[idx] = float("inf")

    def _ee(self, reading: PhysicsReading) -> torch.Tensor:
        return reading.sensordata[:, -1, self._ee_pos]

    def _compute_reward(self, reading: PhysicsReading) -> dict[str, torch.Tensor]:
        self._dist = torch.linalg.vector_norm(self._ee(reading) - reading.mocap_pos[:, 0], dim=-1)
        elapsed = self._step_count.double() * CONTROL_DT
        self._first = first_times(self._dist, self._first, elapsed, self.tolerances)
        return {"dist": 1.0 - torch.tanh(self._dist / DIST_REWARD_LENGTH)}

    def _compute_done(self, reading: PhysicsReading) -> torch.Tensor:
        return torch.zeros(self.num_envs, dtype=torch.bool)

    def _make_obs(self, reading: PhysicsReading) -> dict[str, torch.Tensor]:
        ee = self._ee(reading)
        sphere = reading.mocap_pos[:, 0]
        fingers = reading.qpos[:, N_ARM_JOINTS:N_FRANKA_JOINTS]
        dist = torch.linalg.vector_norm(ee - sphere, dim=-1, keepdim=True)
        return {
            **self._robot_obs(reading),
            "ee_pos": ee.float(),
            "ee_quat": reading.sensordata[:, -1, self._ee_quat].float(),
            "gripper_width": fingers.sum(-1, keepdim=True).float(),
            "state": torch.cat([sphere, ee], dim=-1).float(),
            "object_distance": dist.float(),
            "find_time": self._first.clamp(max=self.episode_seconds).float(),
        }
