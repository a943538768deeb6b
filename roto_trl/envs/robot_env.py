"""What every RoTO task shares: a joint-position-controlled robot with contact sensors.

A task subclasses ``RobotTaskEnv`` and declares, as class attributes, its scene file, robot, tactile
sensor names, default pose and episode metrics; this class maps actions to joint targets, reads
joint angles, velocities and contact forces, and holds the settings common to every task
(``TaskConfig``).

Actions map onto the range each driven joint can really reach (``commanded_range``): its joint
limits, narrowed by any limited fixed tendon through it (the Shadow Hand's coupled middle joints),
never the actuator's control range, which in the kitchen Franka is wider than the joints' ranges
and would leave part of the action range doing nothing.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field
from typing import ClassVar

import mujoco
import numpy as np
import torch
from torchrl.data import Unbounded

from roto_trl.envs.batched_mujoco import BatchedMujocoEnv, PhysicsReading
from roto_trl.envs.rendering import DEFAULT_CAMERA, SceneRenderer
from roto_trl.envs.scene import CONTROL_DT, load_scene

_ONES3 = torch.ones(3, 1, dtype=torch.float64)  # sums a force's three squared components (sensor_force)


def check_field_types(config) -> None:
    """A one-line ``ValueError`` for the first field of a task config whose value is not of its
    declared type: an ``int`` field takes integers only (not ``2.5``, not ``True``), a ``float``
    field finite numbers; ``X | None`` also takes None."""
    hints = typing.get_type_hints(type(config))
    for f in dataclasses.fields(config):
        value, kind = getattr(config, f.name), hints[f.name]
        options = typing.get_args(kind) if isinstance(kind, types.UnionType) else (kind,)
        if value is None and type(None) in options:
            continue
        if int in options and not (isinstance(value, int) and not isinstance(value, bool)):
            raise ValueError(f"{f.name} must be an integer, got {value!r}")
        number = isinstance(value, int | float) and not isinstance(value, bool)
        if float in options and not (number and math.isfinite(value)):
            raise ValueError(f"{f.name} must be a finite number, got {value!r}")


def check_reward_scales(scales: dict) -> None:
    """A one-line ``ValueError`` unless every reward scale is a finite number (NaN or inf would make
    every reward NaN or inf)."""
    for term, value in scales.items():
        number = isinstance(value, int | float) and not isinstance(value, bool)
        if not (number and math.isfinite(value)):
            raise ValueError(f"reward_scales[{term!r}] must be a finite number, got {value!r}")


@dataclass
class TaskConfig:
    """Settings every task has; each field can be overridden in ``make_env``.

    Attributes:
        substeps: physics steps per 60 Hz control step (timestep = 1 / (60 * substeps)).
        episode_steps: control steps before truncation.
        action_ema: smoothing of the joint targets, target <- ema * new + (1 - ema) * old
            (1.0 = none; Find's default is 0.3, as in the authors' release).
        contact_threshold: force in newtons above which a sensor reads 1 (0 = any contact).
        history: number of readings stacked in the policy inputs.
        num_threads: physics worker threads (None: every core this process may use).
        reward_scales: scale of each named reward term.
    """

    substeps: int = 2
    episode_steps: int = 600
    action_ema: float = 1.0
    contact_threshold: float = 0.0
    history: int = 4
    num_threads: int | None = None
    reward_scales: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        check_field_types(self)
        if not 0.0 < self.action_ema <= 1.0:
            raise ValueError(f"action_ema must be in (0, 1], got {self.action_ema}")
        for name in ("substeps", "history", "episode_steps"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.num_threads is not None and self.num_threads < 1:
            raise ValueError(f"num_threads must be >= 1 or None (every core), got {self.num_threads}")
        if self.contact_threshold < 0:
            raise ValueError(f"contact_threshold must be >= 0 N, got {self.contact_threshold}")
        check_reward_scales(self.reward_scales)


def tendon_bounds(
    coef: float, others_low: float, others_high: float, length_low: float, length_high: float
) -> tuple[float, float]:
    """The positions q of one joint that a limited fixed tendon allows.

    The tendon's length is ``coef * q + rest`` with ``rest``, the other joints' part, anywhere in
    ``[others_low, others_high]``; q is allowed when some ``rest`` puts the length in
    ``[length_low, length_high]``.

    Returns:
        ``(low, high)`` of q (``coef`` must be non-zero).
    """
    low, high = (length_low - others_high) / coef, (length_high - others_low) / coef
    return (low, high) if coef > 0 else (high, low)


def commanded_range(m: mujoco.MjModel, actuator: int) -> tuple[float, float]:
    """The joint positions actuator ``actuator`` can drive its joint to.

    The joint's range, narrowed by every limited fixed tendon through the joint (the tendon's
    other joints anywhere in their ranges) and by the actuator's control range, so that a target
    in it is neither clipped by MuJoCo nor beyond where the joint can go.
    """
    joint = int(m.actuator_trnid[actuator, 0])
    low, high = (float(v) for v in m.jnt_range[joint])
    for t in range(m.ntendon):
        adr, num = int(m.tendon_adr[t]), int(m.tendon_num[t])
        wraps = range(adr, adr + num)
        if not m.tendon_limited[t] or any(m.wrap_type[w] != mujoco.mjtWrap.mjWRAP_JOINT for w in wraps):
            continue
        coef = {int(m.wrap_objid[w]): float(m.wrap_prm[w]) for w in wraps}
        if coef.get(joint, 0.0) == 0.0:
            continue
        ends = [(c * m.jnt_range[j, 0], c * m.jnt_range[j, 1]) for j, c in coef.items() if j != joint]
        t_low, t_high = tendon_bounds(
            coef[joint], sum(min(e) for e in ends), sum(max(e) for e in ends), *m.tendon_range[t]
        )
        low, high = max(low, t_low), min(high, t_high)
    if m.actuator_ctrllimited[actuator]:
        ctrl_low, ctrl_high = (float(v) for v in m.actuator_ctrlrange[actuator])
        low, high = max(low, ctrl_low), min(high, ctrl_high)
    if not low < high:
        name = m.actuator(actuator).name
        raise RuntimeError(f"actuator {name} can drive its joint nowhere: range ({low}, {high})")
    return low, high


def sensor_slice(m: mujoco.MjModel, name: str) -> slice:
    """The sensordata columns of the sensor ``name``."""
    sensor = m.sensor(name)
    adr = int(m.sensor_adr[sensor.id])
    return slice(adr, adr + int(m.sensor_dim[sensor.id]))


def sensor_block(names: list[str] | tuple[str, ...], m: mujoco.MjModel) -> slice:
    """The sensordata columns of consecutive 3-D contact-force sensors, as one slice."""
    adr = [int(m.sensor_adr[m.sensor(name).id]) for name in names]
    if any(int(m.sensor_dim[m.sensor(name).id]) != 3 for name in names) or adr != list(
        range(adr[0], adr[0] + 3 * len(adr), 3)
    ):
        raise RuntimeError(f"sensors {names} must be consecutive 3-D force sensors in the scene")
    return slice(adr[0], adr[0] + 3 * len(adr))


def sensor_force(reading: PhysicsReading, block: slice) -> torch.Tensor:
    """Largest force magnitude over the control step's substeps of the sensors in ``block``.

    Returns:
        ``[N, S]`` float32 newtons.
    """
    data = reading.sensordata[:, :, block]
    # The squared components summed by a matmul with ones: on the CPU a reduction over a last
    # dimension of 3 (``vector_norm``, ``sum``) costs twice as much at a few hundred worlds.
    squared = (data * data).reshape(*data.shape[:2], -1, 3) @ _ONES3  # [N, substeps, S, 1]
    return squared.squeeze(-1).amax(dim=1).sqrt_().float()


class RobotTaskEnv(BatchedMujocoEnv):
    """Base of the tasks: action mapping, joint and contact observations, sensor bookkeeping.

    The robot's joints come first in the model and are the ones reported; each actuator drives
    one joint to an absolute target, and the action [-1, 1] of actuator i maps linearly onto
    ``[target_low[i], target_high[i]]`` (``commanded_range``: the joint's reachable range).
    Observation entries (per env): ``joint_pos`` [J] rad (m for slide joints), ``joint_vel`` [J],
    ``contact_force`` [S] N (largest net contact force on each sensor over the control step's
    substeps, so that a contact shorter than a control step is not missed), plus the task's
    ``state`` and episode metrics.

    Class attributes a task sets:
        SCENE: scene file in ``assets/``; ROBOT: robot files to load (``"hand"``, ``"franka"``).
        N_JOINTS: robot joints reported; SENSORS: the tactile sensors' names in the scene, in
            the order of the tactile vector.
        DEFAULT_POSE: actuated joint name (without the robot's prefix) -> target at rest.
        VEL_SCALE: factor on joint velocities in the policy input.
        PROP_EXTRA: entries appended to the proprioception after last action, angles, velocities.
        METRICS: episode metrics reported in every step's output.
        HEADLINE_METRIC: the physical metric (a key of :meth:`physical_metrics`) that the
            results table reports and that picks a run's best checkpoint.
        STATE_NAMES: the elements of the privileged ``state`` output, in order.
        CONFIG: the task's config dataclass.
    """

    SCENE: ClassVar[str]
    ROBOT: ClassVar[str]
    HEADLINE_METRIC: ClassVar[str]
    N_JOINTS: ClassVar[int]
    SENSORS: ClassVar[tuple[str, ...]]
    DEFAULT_POSE: ClassVar[dict[str, float]]
    VEL_SCALE: ClassVar[float]
    PROP_EXTRA: ClassVar[tuple[str, ...]] = ()
    METRICS: ClassVar[tuple[str, ...]]
    STATE_NAMES: ClassVar[tuple[str, ...]]
    CONFIG: ClassVar[type[TaskConfig]]

    def __init__(self, num_envs: int, config: TaskConfig | None = None, *, seed: int = 0, device="cpu"):
        config = self.CONFIG() if config is None else config
        model = load_scene(self.SCENE, self.ROBOT, config.substeps, edit=self._edit_spec)
        self.config = config
        self._index_robot(model)
        super().__init__(
            model,
            num_envs,
            substeps=config.substeps,
            max_episode_steps=config.episode_steps,
            reward_scales=config.reward_scales,
            seed=seed,
            device=device,
            num_threads=config.num_threads,
        )
        self._target = torch.zeros(self.num_envs, model.nu, dtype=torch.float64)
        self.episode_seconds = config.episode_steps * CONTROL_DT

    def _edit_spec(self, spec: mujoco.MjSpec) -> None:
        """Change the parsed scene before it compiles (default: nothing)."""

    def _index_robot(self, m: mujoco.MjModel) -> None:
        names = [m.joint(j).name for j in range(m.njnt)]
        self.joint_names = tuple(names[: self.N_JOINTS])
        self.joint_low = torch.as_tensor(m.jnt_range[: self.N_JOINTS, 0], dtype=torch.float32)
        self.joint_high = torch.as_tensor(m.jnt_range[: self.N_JOINTS, 1], dtype=torch.float32)
        if any(m.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT for a in range(m.nu)):
            raise RuntimeError(f"{self.SCENE}: every actuator must drive one joint")
        ranges = torch.tensor([commanded_range(m, a) for a in range(m.nu)], dtype=torch.float64)
        self.target_low, self.target_high = ranges[:, 0], ranges[:, 1]
        self._act_joint = np.asarray(m.actuator_trnid[:, 0])
        if int(self._act_joint.max()) >= self.N_JOINTS:
            raise RuntimeError(f"{self.SCENE}: an actuator drives a joint past the robot's {self.N_JOINTS}")
        prefix = names[0][: names[0].find(":") + 1]
        self._default_ctrl = np.array(
            [self.DEFAULT_POSE[names[j].removeprefix(prefix)] for j in self._act_joint]
        )
        self._sensor_cols = sensor_block([f"touch:{name}" for name in self.SENSORS], m)

    # ------------------------------------------------------------------ hooks

    @property
    def n_actions(self) -> int:
        return self.mj_model.nu

    def _robot_obs_spec(self) -> dict:
        n = self.num_envs
        return {
            "joint_pos": Unbounded(shape=(n, self.N_JOINTS), dtype=torch.float32),
            "joint_vel": Unbounded(shape=(n, self.N_JOINTS), dtype=torch.float32),
            "contact_force": Unbounded(shape=(n, len(self.SENSORS)), dtype=torch.float32),
        }

    def _robot_obs(self, reading: PhysicsReading) -> dict[str, torch.Tensor]:
        return {
            "joint_pos": reading.qpos[:, : self.N_JOINTS].float(),
            "joint_vel": reading.qvel[:, : self.N_JOINTS].float(),
            "contact_force": sensor_force(reading, self._sensor_cols),
        }

    def targets_for_action(self, action: torch.Tensor) -> torch.Tensor:
        """Joint targets ``[..., nu]`` (float64) of ``action`` ``[..., nu]``: -1 and +1 map onto the
        ends of each joint's ``target_low``/``target_high``, linearly; values outside are clipped."""
        span = self.target_high - self.target_low
        return self.target_low + (action.double().clamp(-1.0, 1.0) + 1.0) * 0.5 * span

    def _prepare_ctrl(self, action: torch.Tensor) -> np.ndarray:
        target = self.targets_for_action(action)
        ema = self.config.action_ema
        self._target = target if ema == 1.0 else ema * target + (1.0 - ema) * self._target
        return self._target.numpy()

    def _ctrl_for_state(self, idx: np.ndarray, qpos: np.ndarray) -> np.ndarray:
        ctrl = np.clip(qpos[:, self._act_joint], self.target_low.numpy(), self.target_high.numpy())
        self._target[idx] = torch.from_numpy(ctrl)
        return ctrl

    # ------------------------------------------------------------------ helpers for users and tests

    def action_for_targets(self, targets: np.ndarray | torch.Tensor) -> torch.Tensor:
        """The action ``[..., nu]`` in [-1, 1] whose joint targets are ``targets`` (clipped)."""
        targets = torch.as_tensor(targets, dtype=torch.float64)
        action = 2.0 * (targets - self.target_low) / (self.target_high - self.target_low) - 1.0
        return action.clamp(-1.0, 1.0).float()

    def default_pose_action(self) -> torch.Tensor:
        """The action ``[nu]`` that holds the task's default pose."""
        return self.action_for_targets(self._default_ctrl)

    def metric_columns(self) -> list[tuple[str, int, str]]:
        """``(key, column, name)`` of each scalar episode metric, e.g. ``("bounces", 0, "bounces")``."""
        columns = []
        for key in self.METRICS:
            width = int(self.observation_spec[key].shape[-1])
            columns += [(key, i, key if width == 1 else f"{key}_{i}") for i in range(width)]
        return columns

    def physical_metrics(self, final: dict[str, torch.Tensor]) -> dict[str, float]:
        """The paper's physical metrics from each episode's final metric values.

        Args:
            final: ``name -> [E]`` (names of :meth:`metric_columns`), one value per episode.

        Returns:
            ``<name>_per_10s``: the count metrics (bounces, rotations) per 10 s of episode time,
            averaged over episodes. An episode that ends early (a dropped ball) keeps its count
            and is scored over the full episode length, so dropping never raises the rate.
        """
        scale = 10.0 / self.episode_seconds
        return {f"{name}_per_10s": float(v.double().mean()) * scale for name, v in final.items()}

    def sensor_bodies(self) -> list[int]:
        """Body id of each tactile sensor, in the order of the tactile vector."""
        m = self.mj_model
        return [int(m.sensor_objid[m.sensor(f"touch:{name}").id]) for name in self.SENSORS]

    def render(
        self,
        env_index: int = 0,
        *,
        camera: str = DEFAULT_CAMERA,
        width: int = 640,
        height: int = 480,
        show_contacts: bool = True,
    ) -> np.ndarray:
        """An RGB frame ``[height, width, 3]`` uint8 of world ``env_index`` as it is now.

        With ``show_contacts`` the links (or pads) whose sensor reads 1 in the latest step are
        drawn lit. Offscreen; on a machine without a display set ``MUJOCO_GL=egl`` (or
        ``osmesa``) before Python starts (see ``roto_trl.envs.rendering``).
        """
        if not 0 <= int(env_index) < self.num_envs:
            raise IndexError(f"env_index {env_index} out of range for {self.num_envs} envs")
        key = (camera, int(width), int(height))
        if getattr(self, "_renderer_key", None) != key:
            self.close_renderer()
            self._renderer = SceneRenderer(self.mj_model, camera, int(width), int(height))
            self._renderer_key = key
        lit: list[int] = []
        if show_contacts:
            force = sensor_force(self._reading(), self._sensor_cols)[int(env_index)]
            bodies = self.sensor_bodies()
            lit = [bodies[s] for s in range(len(bodies)) if force[s] > self.config.contact_threshold]
        i = int(env_index)
        return self._renderer.frame(self._state[i], self._mocap_pos[i], lit)

    def close_renderer(self) -> None:
        """Free the offscreen GL context, if ``render`` made one."""
        renderer = getattr(self, "_renderer", None)
        if renderer is not None:
            renderer.close()
            self._renderer = self._renderer_key = None

    def close(self, *, raise_if_closed: bool = True) -> None:
        self.close_renderer()
        super().close(raise_if_closed=raise_if_closed)
