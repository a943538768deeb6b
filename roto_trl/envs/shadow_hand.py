"""What the Shadow Hand tasks share: the hand's joints, actuators, 17 link sensors and reset.

The hand is the OpenAI Shadow Hand of gymnasium-robotics (24 joints, 20 position actuators; the
distal joint of each finger is coupled to its middle joint by a fixed tendon), mounted palm up
and fixed in mid-air by ``assets/shadow_hand.xml``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torchrl.data import Unbounded

from roto_trl.envs.robot_env import RobotTaskEnv, TaskConfig

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


@dataclass
class ShadowTaskConfig(TaskConfig):
    """Settings of the Shadow Hand tasks (see ``TaskConfig`` for the common ones).

    Attributes:
        hand_reset_noise: at reset each joint moves this fraction of the way from the default
            pose towards a point drawn uniformly in the range its action spans (Isaac Lab's
            convention for "+-20 % around the default pose").
    """

    hand_reset_noise: float = 0.2

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0.0 <= self.hand_reset_noise <= 1.0:
            raise ValueError(f"hand_reset_noise must be in [0, 1], got {self.hand_reset_noise}")


class ShadowHandEnv(RobotTaskEnv):
    """Base of the Shadow Hand tasks: the hand's checks, its coupled joints and its reset.

    Observation entries (per env): ``joint_pos`` [24] rad, ``joint_vel`` [24] rad/s,
    ``contact_force`` [17] N (one per link, ``SENSOR_LINKS``), plus the task's ``state`` and
    episode metrics.
    """

    ROBOT = "hand"
    N_JOINTS = N_HAND_JOINTS
    SENSORS = SENSOR_LINKS
    DEFAULT_POSE = CUPPED_POSE
    VEL_SCALE = 0.2

    def _make_obs_spec(self) -> dict:
        """The robot's entries, the privileged ``state`` [len(STATE_NAMES)] and one ``[1]`` entry
        per episode metric (``METRICS``)."""
        n = self.num_envs
        return {
            **self._robot_obs_spec(),
            "state": Unbounded(shape=(n, len(self.STATE_NAMES)), dtype=torch.float32),
            **{metric: Unbounded(shape=(n, 1), dtype=torch.float32) for metric in self.METRICS},
        }

    def _index_robot(self, m) -> None:
        names = [m.joint(j).name for j in range(m.njnt)]
        hand = [j for j, name in enumerate(names) if name.startswith("robot0:")]
        if hand != list(range(N_HAND_JOINTS)) or m.nu != N_HAND_ACTUATORS:
            raise RuntimeError(
                f"{self.SCENE}: expected the hand's {N_HAND_JOINTS} joints first and "
                f"{N_HAND_ACTUATORS} actuators, got joints {hand} and {m.nu} actuators"
            )
        super()._index_robot(m)
        # Coupled distal joints: a fixed tendon c0 * q_distal + c1 * q_middle held near zero.
        self._coupled = []
        for t in range(m.ntendon):
            if m.tendon(t).name.endswith("J1c"):
                adr = m.tendon_adr[t]
                (j0, j1), (c0, c1) = m.wrap_objid[adr : adr + 2], m.wrap_prm[adr : adr + 2]
                self._coupled.append((int(j0), int(j1), -float(c1) / float(c0)))

    def _sample_hand(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hand joint positions ``[n, 24]`` and actuator targets ``[n, 20]`` for a new episode."""
        n = len(idx)
        low, high = self.target_low.numpy(), self.target_high.numpy()
        toward = self.rng.uniform(low, high, size=(n, N_HAND_ACTUATORS))
        ctrl = self._default_ctrl + self.config.hand_reset_noise * (toward - self._default_ctrl)
        qpos = np.zeros((n, N_HAND_JOINTS))
        qpos[:, self._act_joint] = ctrl
        low, high = self.joint_low.double().numpy(), self.joint_high.double().numpy()
        for distal, middle, ratio in self._coupled:
            qpos[:, distal] = np.clip(ratio * qpos[:, middle], low[distal], high[distal])
        self._target[idx] = torch.from_numpy(ctrl)
        return qpos, ctrl
