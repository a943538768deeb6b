"""What the Shadow Hand tasks share: the hand's joints, actuators, 17 link sensors and reset.

The hand is the OpenAI Shadow Hand of gymnasium-robotics (24 joints, 20 position actuators; the
distal joint of each finger is coupled to its middle joint by a fixed tendon), mounted palm up
and fixed in mid-air by ``assets/shadow_hand.xml``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import torch
from torchrl.data import Unbounded

from roto_trl.envs.batched_mujoco import BatchedMujocoEnv, PhysicsReading
from roto_trl.envs.scene import load_scene

# Order of the tactile vector: 5 distal, 5 middle, 5 proximal (thumb included), palm, metacarpal.
SENSOR_LINKS = (
    "ffdistal", "mfdistal", "rfdistal", "lfdistal", "thdistal",
    "ffmiddle", "mfmiddle", "rfmiddle", "lfmiddle", "thmiddle",
    "ffproximal", "mfproximal", "rfproximal", "lfproximal", "thproximal",
    "palm", "lfmetacarpal",
)  # fmt: skip
N_HAND_JOINTS = 24
N_HAND_ACTUATORS = 20

# A cupped, palm-up pose, tilted 6 degrees towards the fingertips, in which the Bounce ball and
# the Baoding balls rest against the curled fingers (radians, by the
# actuated joint's name; the coupled distal joints follow their middle joints).
CUPPED_POSE = {
    "WRJ1": 0.0, "WRJ0": -0.1,
    "FFJ3": 0.0, "FFJ2": 0.5, "FFJ1": 0.4,
    "MFJ3": 0.0, "MFJ2": 0.5, "MFJ1": 0.4,
    "RFJ3": 0.0, "RFJ2": 0.5, "RFJ1": 0.4,
    "LFJ4": 0.4, "LFJ3": 0.0, "LFJ2": 0.5, "LFJ1": 0.4,
    "THJ4": 0.2, "THJ3": 0.6, "THJ2": 0.1, "THJ1": 0.3, "THJ0": -0.2,
}  # fmt: skip


def sensor_block(names: list[str], m) -> slice:
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
    force = data.reshape(*data.shape[:2], -1, 3)  # [N, substeps, S, 3]
    return torch.linalg.vector_norm(force, dim=-1).amax(dim=1).float()


@dataclass
class ShadowTaskConfig:
    """Settings shared by the Shadow Hand tasks; every field can be overridden in ``make_env``.

    Attributes:
        substeps: physics steps per 60 Hz control step (timestep = 1 / (60 * substeps)).
        episode_steps: control steps before truncation.
        action_ema: smoothing of the joint targets, target <- ema * new + (1 - ema) * old
            (1.0 = none).
        hand_reset_noise: at reset each joint moves this fraction of the way from the default
            pose towards a point drawn uniformly in its range (Isaac Lab's convention for
            "+-20 % around the default pose").
        contact_threshold: force in newtons above which a link sensor reads 1 (0 = any contact).
        history: number of readings stacked in the policy inputs.
        num_threads: physics worker threads (None: every core this process may use).
        reward_scales: scale of each named reward term.
    """

    substeps: int = 2
    episode_steps: int = 600
    action_ema: float = 1.0
    hand_reset_noise: float = 0.2
    contact_threshold: float = 0.0
    history: int = 4
    num_threads: int | None = None
    reward_scales: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not 0.0 < self.action_ema <= 1.0:
            raise ValueError(f"action_ema must be in (0, 1], got {self.action_ema}")
        if int(self.history) < 1:
            raise ValueError(f"history must be >= 1, got {self.history}")
        if int(self.episode_steps) < 1:
            raise ValueError(f"episode_steps must be >= 1, got {self.episode_steps}")
        if not 0.0 <= self.hand_reset_noise <= 1.0:
            raise ValueError(f"hand_reset_noise must be in [0, 1], got {self.hand_reset_noise}")


class ShadowHandEnv(BatchedMujocoEnv):
    """Base of the Shadow Hand tasks: action mapping, hand observations, hand reset.

    Observation entries (per env): ``joint_pos`` [24] rad, ``joint_vel`` [24] rad/s,
    ``contact_force`` [17] N (largest net contact force on each link over the control step's
    substeps, so that a contact shorter than a control step is not missed), plus the task's
    ``state`` and episode metrics.
    """

    SCENE: ClassVar[str]
    DEFAULT_POSE: ClassVar[dict[str, float]] = CUPPED_POSE

    def __init__(self, num_envs: int, config: ShadowTaskConfig, *, seed: int = 0, device="cpu"):
        model = load_scene(self.SCENE, "hand", config.substeps)
        self.config = config
        self._index_hand(model)
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
        self._target = torch.zeros(self.num_envs, N_HAND_ACTUATORS, dtype=torch.float64)

    # ------------------------------------------------------------------ model indexing

    def _index_hand(self, m) -> None:
        names = [m.joint(j).name for j in range(m.njnt)]
        hand = [j for j, name in enumerate(names) if name.startswith("robot0:")]
        if hand != list(range(N_HAND_JOINTS)) or m.nu != N_HAND_ACTUATORS:
            raise RuntimeError(
                f"{self.SCENE}: expected the hand's {N_HAND_JOINTS} joints first and "
                f"{N_HAND_ACTUATORS} actuators, got joints {hand} and {m.nu} actuators"
            )
        self.joint_names = tuple(names[:N_HAND_JOINTS])
        self.joint_low = torch.as_tensor(m.jnt_range[:N_HAND_JOINTS, 0], dtype=torch.float32)
        self.joint_high = torch.as_tensor(m.jnt_range[:N_HAND_JOINTS, 1], dtype=torch.float32)
        self._ctrl_lo = torch.as_tensor(m.actuator_ctrlrange[:, 0])
        self._ctrl_span = torch.as_tensor(m.actuator_ctrlrange[:, 1] - m.actuator_ctrlrange[:, 0])
        self._act_joint = np.asarray(m.actuator_trnid[:, 0])
        pose = np.zeros(m.nu)
        for a in range(m.nu):
            short = names[self._act_joint[a]].removeprefix("robot0:")
            pose[a] = self.DEFAULT_POSE[short]
        self._default_ctrl = pose
        # Coupled distal joints: a fixed tendon c0 * q_distal + c1 * q_middle held near zero.
        self._coupled = []
        for t in range(m.ntendon):
            if m.tendon(t).name.endswith("J1c"):
                adr = m.tendon_adr[t]
                (j0, j1), (c0, c1) = m.wrap_objid[adr : adr + 2], m.wrap_prm[adr : adr + 2]
                self._coupled.append((int(j0), int(j1), -float(c1) / float(c0)))
        self._link_sensors = sensor_block([f"touch:{link}" for link in SENSOR_LINKS], m)

    # ------------------------------------------------------------------ hooks

    @property
    def n_actions(self) -> int:
        return N_HAND_ACTUATORS

    def _hand_obs_spec(self) -> dict:
        n = self.num_envs
        return {
            "joint_pos": Unbounded(shape=(n, N_HAND_JOINTS), dtype=torch.float32),
            "joint_vel": Unbounded(shape=(n, N_HAND_JOINTS), dtype=torch.float32),
            "contact_force": Unbounded(shape=(n, len(SENSOR_LINKS)), dtype=torch.float32),
        }

    def _hand_obs(self, reading: PhysicsReading) -> dict[str, torch.Tensor]:
        return {
            "joint_pos": reading.qpos[:, :N_HAND_JOINTS].float(),
            "joint_vel": reading.qvel[:, :N_HAND_JOINTS].float(),
            "contact_force": sensor_force(reading, self._link_sensors),
        }

    def _prepare_ctrl(self, action: torch.Tensor) -> np.ndarray:
        target = self._ctrl_lo + (action.double().clamp(-1.0, 1.0) + 1.0) * 0.5 * self._ctrl_span
        ema = self.config.action_ema
        self._target = target if ema == 1.0 else ema * target + (1.0 - ema) * self._target
        return self._target.numpy()

    def action_for_targets(self, targets: np.ndarray | torch.Tensor) -> torch.Tensor:
        """The action ``[..., 20]`` in [-1, 1] whose joint targets are ``targets`` (rad, clipped)."""
        targets = torch.as_tensor(targets, dtype=torch.float64)
        action = 2.0 * (targets - self._ctrl_lo) / self._ctrl_span - 1.0
        return action.clamp(-1.0, 1.0).float()

    def default_pose_action(self) -> torch.Tensor:
        """The action ``[20]`` that holds the task's default (cupped) pose."""
        return self.action_for_targets(self._default_ctrl)

    def _ctrl_for_state(self, idx: np.ndarray, qpos: np.ndarray) -> np.ndarray:
        lo = self._ctrl_lo.numpy()
        ctrl = np.clip(qpos[:, self._act_joint], lo, lo + self._ctrl_span.numpy())
        self._target[idx] = torch.from_numpy(ctrl)
        return ctrl

    def _sample_hand(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hand joint positions ``[n, 24]`` and actuator targets ``[n, 20]`` for a new episode."""
        n = len(idx)
        lo = self._ctrl_lo.numpy()
        hi = lo + self._ctrl_span.numpy()
        toward = self.rng.uniform(lo, hi, size=(n, N_HAND_ACTUATORS))
        ctrl = self._default_ctrl + self.config.hand_reset_noise * (toward - self._default_ctrl)
        qpos = np.zeros((n, N_HAND_JOINTS))
        qpos[:, self._act_joint] = ctrl
        low, high = self.joint_low.double().numpy(), self.joint_high.double().numpy()
        for distal, middle, ratio in self._coupled:
            qpos[:, distal] = np.clip(ratio * qpos[:, middle], low[distal], high[distal])
        self._target[idx] = torch.from_numpy(ctrl)
        return qpos, ctrl
