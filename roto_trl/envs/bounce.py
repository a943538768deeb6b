"""Bounce: bounce a 70 mm, 30 g stress ball on the palm-up Shadow Hand as often as possible.

A bounce is a contact of the ball with the hand after at least ``BOUNCE_MIN_FREE_STEPS`` control
steps without one. The ball's own contact sensor (``ball:touch`` in ``assets/bounce.xml``)
decides, not the 17 link sensors: those also fire when two fingers touch, which a policy could
otherwise tap for reward. Rewards (the paper's Table A2, summed after scaling by the config):
``air`` = steps since the ball last touched the hand (every step), ``bounce`` = 1 per bounce,
``fall`` = -1 when the ball is more than ``FALL_RADIUS`` from ``FALL_CENTRE`` (the episode ends).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from roto_trl.envs.batched_mujoco import PhysicsReading
from roto_trl.envs.robot_env import sensor_block, sensor_force
from roto_trl.envs.shadow_hand import N_HAND_JOINTS, ShadowHandEnv, ShadowTaskConfig

SCENE = "bounce.xml"
BALL_REST = (-0.018, -0.0945, 0.336)  # where the ball settles in the cupped default pose (m)
BALL_START_LIFT = 0.012  # start above the rest point so the +-1 cm noise never starts inside
BALL_START_NOISE = 0.01  # +- on each axis (m)
FALL_CENTRE = BALL_REST
FALL_RADIUS = 0.24
BOUNCE_MIN_FREE_STEPS = 5
REWARD_SCALES = {"air": 0.01, "bounce": 10.0, "fall": 10.0}
# the privileged state (never an agent input; the mutual-information analysis reads it), in order:
# ball position, quaternion (w, x, y, z), linear velocity (world), angular velocity (body), free steps
STATE_NAMES = (
    *("ball_x", "ball_y", "ball_z"),
    *("ball_qw", "ball_qx", "ball_qy", "ball_qz"),
    *("ball_vx", "ball_vy", "ball_vz"),
    *("ball_wx", "ball_wy", "ball_wz"),
    "free_steps",
)


def count_bounces(
    in_contact: torch.Tensor, free_steps: torch.Tensor, min_free_steps: int = BOUNCE_MIN_FREE_STEPS
) -> tuple[torch.Tensor, torch.Tensor]:
    """Advance the bounce detector by one control step.

    Args:
        in_contact: ``[N]`` bool, the ball touches the hand in this step.
        free_steps: ``[N]`` long, steps without contact before this step.
        min_free_steps: a contact after at least this many free steps is a bounce.

    Returns:
        ``(bounced [N] bool, free_steps [N] long)`` after this step.
    """
    bounced = in_contact & (free_steps >= min_free_steps)
    return bounced, torch.where(in_contact, torch.zeros_like(free_steps), free_steps + 1)


@dataclass
class BounceConfig(ShadowTaskConfig):
    reward_scales: dict[str, float] = field(default_factory=lambda: dict(REWARD_SCALES))


class BounceEnv(ShadowHandEnv):
    """Bounce on the Shadow Hand. Metric ``bounces``: bounces so far in the episode."""

    SCENE = SCENE
    CONFIG = BounceConfig
    METRICS = ("bounces",)  # episode metrics reported in every step's output
    HEADLINE_METRIC = "bounces_per_10s"
    STATE_NAMES = STATE_NAMES

    def __init__(self, num_envs: int, config: BounceConfig | None = None, **kwargs):
        super().__init__(num_envs, config, **kwargs)
        m = self.mj_model
        ball = m.joint("ball")
        self._ball_q = int(m.jnt_qposadr[ball.id])
        self._ball_v = int(m.jnt_dofadr[ball.id])
        self._ball_sensor = sensor_block(["ball:touch"], m)
        self._free_steps = torch.zeros(self.num_envs, dtype=torch.long)
        self._bounces = torch.zeros(self.num_envs, dtype=torch.long)
        self._fallen = torch.zeros(self.num_envs, dtype=torch.bool)
        self._centre = torch.tensor(FALL_CENTRE, dtype=torch.float64)

    def _sample_initial_state(self, idx: np.ndarray):
        n = len(idx)
        hand_q, ctrl = self._sample_hand(idx)
        qpos = np.zeros((n, self.mj_model.nq))
        qpos[:, :N_HAND_JOINTS] = hand_q
        start = np.add(BALL_REST, (0.0, 0.0, BALL_START_LIFT))
        qpos[:, self._ball_q : self._ball_q + 3] = start + self.rng.uniform(
            -BALL_START_NOISE, BALL_START_NOISE, size=(n, 3)
        )
        qpos[:, self._ball_q + 3] = 1.0  # identity quaternion
        return qpos, np.zeros((n, self.mj_model.nv)), ctrl

    def _on_reset_mask(self, idx: np.ndarray) -> None:
        self._free_steps[idx] = 0
        self._bounces[idx] = 0

    def _ball_pos(self, reading: PhysicsReading) -> torch.Tensor:
        return reading.qpos[:, self._ball_q : self._ball_q + 3]

    def _compute_reward(self, reading: PhysicsReading) -> dict[str, torch.Tensor]:
        in_contact = sensor_force(reading, self._ball_sensor)[:, 0] > 0.0
        bounced, self._free_steps = count_bounces(in_contact, self._free_steps)
        self._bounces += bounced
        dist = torch.linalg.vector_norm(self._ball_pos(reading) - self._centre, dim=-1)
        self._fallen = dist > FALL_RADIUS
        return {
            "air": self._free_steps.double(),
            "bounce": bounced.double(),
            "fall": -self._fallen.double(),
        }

    def _compute_done(self, reading: PhysicsReading) -> torch.Tensor:
        return self._fallen  # computed with the reward, from the same reading

    def _make_obs(self, reading: PhysicsReading) -> dict[str, torch.Tensor]:
        q, v = self._ball_q, self._ball_v
        state = torch.cat(
            [
                reading.qpos[:, q : q + 7],  # position, quaternion (w, x, y, z)
                reading.qvel[:, v : v + 6],  # linear (world frame), angular (body frame) velocity
                self._free_steps.double().unsqueeze(-1),
            ],
            dim=-1,
        )
        return {
            **self._robot_obs(reading),
            "state": state.float(),
            "bounces": self._bounces.float().unsqueeze(-1),
        }
