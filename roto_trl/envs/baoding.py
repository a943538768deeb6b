"""Baoding: rotate two 1.5 in (38.1 mm), 55 g balls around each other in the palm.

Two virtual targets are fixed in the world where the balls rest in the default cupped pose. Ball
A starts on target 1 and is sent to target 2, ball B the other way; when both centres are within
``SWAP_TOLERANCE`` of their targets the targets swap (``rotation`` reward). Two swaps bring each
ball back to its start: one complete rotation. Rewards (the paper's Table A2, scaled by the
config): ``dist_a``/``dist_b`` = 1 - tanh(d / 0.1) per ball, ``rotation`` = 1 per swap,
``fall`` = -1 when the balls are more than ``MAX_BALL_SEPARATION`` apart or a ball is more than
``MAX_DIST_FROM_HAND`` from the middle of the targets (the episode ends).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from roto_trl.envs.batched_mujoco import PhysicsReading
from roto_trl.envs.shadow_hand import N_HAND_JOINTS, ShadowHandEnv, ShadowTaskConfig

SCENE = "baoding.xml"
TARGETS = ((-0.020, -0.097, 0.317), (0.004, -0.0675, 0.322))  # rest points of the balls (m)
BALL_START_LIFT = 0.006  # start above the rest points so the +-0.5 cm noise never starts inside
BALL_START_NOISE = 0.005  # +- on each axis (m)
SWAP_TOLERANCE = 0.01
DIST_REWARD_LENGTH = 0.1
MAX_BALL_SEPARATION = 0.15
MAX_DIST_FROM_HAND = 0.10
REWARD_SCALES = {"dist_a": 0.1, "dist_b": 0.1, "rotation": 10.0, "fall": 10.0}
# the privileged state (never an agent input; the mutual-information analysis reads it), in order
STATE_NAMES = (
    *("a_x", "a_y", "a_z", "b_x", "b_y", "b_z"),  # ball positions
    *("a_vx", "a_vy", "a_vz", "b_vx", "b_vy", "b_vz"),  # linear velocities
    "ball_distance",
)


def swap_targets(
    dist_a: torch.Tensor, dist_b: torch.Tensor, phase: torch.Tensor, tolerance: float = SWAP_TOLERANCE
) -> tuple[torch.Tensor, torch.Tensor]:
    """Advance the target-swap logic by one control step.

    Args:
        dist_a, dist_b: ``[N]`` distances of each ball to its current target (m).
        phase: ``[N]`` long, swaps so far this episode; ball A's target is ``TARGETS[1 - phase % 2]``.
        tolerance: both balls must be closer than this to swap.

    Returns:
        ``(swapped [N] bool, phase [N] long)``.
    """
    swapped = (dist_a < tolerance) & (dist_b < tolerance)
    return swapped, phase + swapped.long()


def balls_fell(pos_a: torch.Tensor, pos_b: torch.Tensor, hand_centre: torch.Tensor) -> torch.Tensor:
    """``[N]`` bool: the balls are too far apart, or one has left the hand."""
    apart = torch.linalg.vector_norm(pos_a - pos_b, dim=-1) > MAX_BALL_SEPARATION
    out_a = torch.linalg.vector_norm(pos_a - hand_centre, dim=-1) > MAX_DIST_FROM_HAND
    out_b = torch.linalg.vector_norm(pos_b - hand_centre, dim=-1) > MAX_DIST_FROM_HAND
    return apart | out_a | out_b


def complete_rotations(swaps: torch.Tensor) -> torch.Tensor:
    """Complete rotations (each ball back at its start) from the number of swaps: two per rotation."""
    return torch.div(swaps, 2, rounding_mode="floor")


@dataclass
class BaodingConfig(ShadowTaskConfig):
    reward_scales: dict[str, float] = field(default_factory=lambda: dict(REWARD_SCALES))


class BaodingEnv(ShadowHandEnv):
    """Baoding on the Shadow Hand. Metric ``rotations``: complete rotations so far this episode."""

    SCENE = SCENE
    CONFIG = BaodingConfig
    METRICS = ("rotations",)  # episode metrics reported in every step's output
    HEADLINE_METRIC = "rotations_per_10s"
    STATE_NAMES = STATE_NAMES

    def __init__(self, num_envs: int, config: BaodingConfig | None = None, **kwargs):
        super().__init__(num_envs, config, **kwargs)
        m = self.mj_model
        self._ball_q = [int(m.jnt_qposadr[m.joint(b).id]) for b in ("ball_a", "ball_b")]
        self._ball_v = [int(m.jnt_dofadr[m.joint(b).id]) for b in ("ball_a", "ball_b")]
        self._targets = torch.tensor(TARGETS, dtype=torch.float64)
        self._hand_centre = self._targets.mean(0)
        self._swaps = torch.zeros(self.num_envs, dtype=torch.long)
        self._fallen = torch.zeros(self.num_envs, dtype=torch.bool)

    def _sample_initial_state(self, idx: np.ndarray):
        n = len(idx)
        hand_q, ctrl = self._sample_hand(idx)
        qpos = np.zeros((n, self.mj_model.nq))
        qpos[:, :N_HAND_JOINTS] = hand_q
        for q, target in zip(self._ball_q, TARGETS, strict=True):
            start = np.add(target, (0.0, 0.0, BALL_START_LIFT))
            noise = self.rng.uniform(-BALL_START_NOISE, BALL_START_NOISE, size=(n, 3))
            qpos[:, q : q + 3] = start + noise
            qpos[:, q + 3] = 1.0  # identity quaternion
        return qpos, np.zeros((n, self.mj_model.nv)), ctrl

    def _on_reset_mask(self, idx: np.ndarray) -> None:
        self._swaps[idx] = 0

    def _ball_positions(self, reading: PhysicsReading) -> tuple[torch.Tensor, torch.Tensor]:
        a, b = self._ball_q
        return reading.qpos[:, a : a + 3], reading.qpos[:, b : b + 3]

    def _compute_reward(self, reading: PhysicsReading) -> dict[str, torch.Tensor]:
        pos_a, pos_b = self._ball_positions(reading)
        a_goes_to_2 = (self._swaps % 2 == 0).unsqueeze(-1)
        target_a = torch.where(a_goes_to_2, self._targets[1], self._targets[0])
        target_b = torch.where(a_goes_to_2, self._targets[0], self._targets[1])
        dist_a = torch.linalg.vector_norm(pos_a - target_a, dim=-1)
        dist_b = torch.linalg.vector_norm(pos_b - target_b, dim=-1)
        swapped, self._swaps = swap_targets(dist_a, dist_b, self._swaps)
        self._fallen = balls_fell(pos_a, pos_b, self._hand_centre)
        return {
            "dist_a": 1.0 - torch.tanh(dist_a / DIST_REWARD_LENGTH),
            "dist_b": 1.0 - torch.tanh(dist_b / DIST_REWARD_LENGTH),
            "rotation": swapped.double(),
            "fall": -self._fallen.double(),
        }

    def _compute_done(self, reading: PhysicsReading) -> torch.Tensor:
        return self._fallen  # computed with the reward, from the same reading

    def _make_obs(self, reading: PhysicsReading) -> dict[str, torch.Tensor]:
        pos_a, pos_b = self._ball_positions(reading)
        va, vb = self._ball_v
        state = torch.cat(
            [
                pos_a,
                pos_b,
                reading.qvel[:, va : va + 3],
                reading.qvel[:, vb : vb + 3],
                torch.linalg.vector_norm(pos_a - pos_b, dim=-1, keepdim=True),
            ],
            dim=-1,
        )
        return {
            **self._robot_obs(reading),
            "state": state.float(),
            "rotations": complete_rotations(self._swaps).float().unsqueeze(-1),
        }
