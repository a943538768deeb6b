"""Baoding: rotate two 1.5 in (38.1 mm), 55 g balls around each other in the palm.

Two virtual targets are fixed in the world where the balls rest in the default cupped pose. Ball
A starts on target 1 and is sent to target 2, ball B the other way; when the swap rule is met the
targets swap (``rotation`` reward). Two swaps bring each ball back to its start: one complete
rotation. The swap rule (``BaodingConfig.swap_rule``):

- ``latched`` (default; the authors' released code, which produced every rotation figure they
  published): a ball is marked when its centre comes within ``SWAP_TOLERANCE`` of its target and
  keeps the mark; when both are marked the targets swap, the bonus is paid and the marks clear.
- ``simultaneous`` (the paper's sentence): both centres within ``SWAP_TOLERANCE`` at one step.

Either rule pays a shuffle (one ball pushed onto the other's target) as a swap. ``turns`` cannot
be shuffled: the signed angle that the ball-to-ball vector sweeps about the palm's normal,
unwrapped over the episode, in whole turns (+ counter-clockwise seen from above the palm).

Rewards (the paper's Table A2, scaled by the config): ``dist_a``/``dist_b`` = 1 - tanh(d / 0.1)
per ball, ``rotation`` = 1 per swap, ``fall`` = -1 when the balls are ``MAX_BALL_SEPARATION`` or
more apart, which ends the episode (the paper and the authors' code agree on this condition).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from roto_trl.envs.batched_mujoco import PhysicsReading
from roto_trl.envs.robot_env import sensor_slice
from roto_trl.envs.shadow_hand import N_HAND_JOINTS, ShadowHandEnv, ShadowTaskConfig

SCENE = "baoding.xml"
TARGETS = ((-0.020, -0.097, 0.317), (0.004, -0.0675, 0.322))  # rest points of the balls (m)
BALL_START_LIFT = 0.006  # start above the rest points so the +-0.5 cm noise never starts inside
BALL_START_NOISE = 0.005  # +- on each axis (m)
SWAP_TOLERANCE = 0.01
DIST_REWARD_LENGTH = 0.1
MAX_BALL_SEPARATION = 0.15
SWAP_RULES = ("latched", "simultaneous")
REWARD_SCALES = {"dist_a": 0.1, "dist_b": 0.1, "rotation": 10.0, "fall": 10.0}
# the privileged state (never an agent input; the mutual-information analysis reads it), in order
STATE_NAMES = (
    *("a_x", "a_y", "a_z", "b_x", "b_y", "b_z"),  # ball positions
    *("a_vx", "a_vy", "a_vz", "b_vx", "b_vy", "b_vz"),  # linear velocities
    "ball_distance",
)


def swap_targets(
    dist_a: torch.Tensor,
    dist_b: torch.Tensor,
    phase: torch.Tensor,
    marks: torch.Tensor,
    rule: str = "latched",
    tolerance: float = SWAP_TOLERANCE,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Advance the target-swap logic by one control step.

    Args:
        dist_a, dist_b: ``[N]`` distances of each ball to its current target (m).
        phase: ``[N]`` long, swaps so far this episode; ball A's target is ``TARGETS[1 - phase % 2]``.
        marks: ``[N, 2]`` bool, whether ball A / B has reached its current target (``latched``).
        rule: ``latched`` or ``simultaneous`` (module docstring).
        tolerance: a ball within this of its target reaches it.

    Returns:
        ``(swapped [N] bool, phase [N] long, marks [N, 2] bool)``.
    """
    near = torch.stack([dist_a < tolerance, dist_b < tolerance], dim=-1)
    if rule == "simultaneous":
        swapped = near.all(-1)
        return swapped, phase + swapped.long(), marks
    marks = marks | near
    swapped = marks.all(-1)
    return swapped, phase + swapped.long(), marks & ~swapped.unsqueeze(-1)


def balls_fell(pos_a: torch.Tensor, pos_b: torch.Tensor) -> torch.Tensor:
    """``[N]`` bool: the balls are ``MAX_BALL_SEPARATION`` or more apart (one has left the hand)."""
    return torch.linalg.vector_norm(pos_a - pos_b, dim=-1) >= MAX_BALL_SEPARATION


def complete_rotations(swaps: torch.Tensor) -> torch.Tensor:
    """Complete rotations (each ball back at its start) from the number of swaps: two per rotation."""
    return torch.div(swaps, 2, rounding_mode="floor")


def pair_angle(pos_a: torch.Tensor, pos_b: torch.Tensor, normal: torch.Tensor) -> torch.Tensor:
    """The angle ``[N]`` (rad) of the ball-to-ball vector ``pos_b - pos_a`` ``[N, 3]`` in the plane
    perpendicular to ``normal`` ``[N, 3]`` (unit), measured counter-clockwise about the normal from
    the world x axis projected into that plane."""
    x = torch.zeros_like(normal)
    x[:, 0] = 1.0
    e1 = x - (x * normal).sum(-1, keepdim=True) * normal
    e1 = e1 / torch.linalg.vector_norm(e1, dim=-1, keepdim=True)
    e2 = torch.linalg.cross(normal, e1, dim=-1)
    v = pos_b - pos_a
    return torch.atan2((v * e2).sum(-1), (v * e1).sum(-1))


def unwrapped_step(angle: torch.Tensor, previous: torch.Tensor) -> torch.Tensor:
    """The change ``[N]`` from ``previous`` to ``angle`` (rad) taken the short way, in (-pi, pi];
    0 where ``previous`` is NaN (the first step of an episode)."""
    delta = torch.atan2(torch.sin(angle - previous), torch.cos(angle - previous))
    return torch.nan_to_num(delta, nan=0.0)


@dataclass
class BaodingConfig(ShadowTaskConfig):
    """Baoding's settings (``ShadowTaskConfig``'s and these).

    Attributes:
        swap_rule: ``latched`` (the authors' code) or ``simultaneous`` (the paper's sentence).
    """

    reward_scales: dict[str, float] = field(default_factory=lambda: dict(REWARD_SCALES))
    swap_rule: str = "latched"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.swap_rule not in SWAP_RULES:
            raise ValueError(f"swap_rule must be one of {list(SWAP_RULES)}, got {self.swap_rule!r}")


class BaodingEnv(ShadowHandEnv):
    """Baoding on the Shadow Hand. Metrics ``rotations`` (complete rotations so far this episode)
    and ``turns`` (the signed turns of the ball pair so far)."""

    SCENE = SCENE
    CONFIG = BaodingConfig
    METRICS = ("rotations", "turns")  # episode metrics reported in every step's output
    HEADLINE_METRIC = "rotations_per_10s"
    STATE_NAMES = STATE_NAMES

    def __init__(self, num_envs: int, config: BaodingConfig | None = None, **kwargs):
        super().__init__(num_envs, config, **kwargs)
        m = self.mj_model
        self._ball_q = [int(m.jnt_qposadr[m.joint(b).id]) for b in ("ball_a", "ball_b")]
        self._ball_v = [int(m.jnt_dofadr[m.joint(b).id]) for b in ("ball_a", "ball_b")]
        self._palm_y = sensor_slice(m, "palm:y")
        self._targets = torch.tensor(TARGETS, dtype=torch.float64)
        self._swaps = torch.zeros(self.num_envs, dtype=torch.long)
        self._marks = torch.zeros(self.num_envs, 2, dtype=torch.bool)
        self._angle = torch.full((self.num_envs,), math.nan, dtype=torch.float64)  # last step's
        self._turned = torch.zeros(self.num_envs, dtype=torch.float64)  # rad, this episode
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
        # a new episode starts unmarked, with ball A sent to target 2, and no turn yet
        self._swaps[idx] = 0
        self._marks[idx] = False
        self._angle[idx] = math.nan
        self._turned[idx] = 0.0

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
        swapped, self._swaps, self._marks = swap_targets(
            dist_a, dist_b, self._swaps, self._marks, self.config.swap_rule
        )
        normal = -reading.sensordata[:, -1, self._palm_y]
        angle = pair_angle(pos_a, pos_b, normal)
        self._turned += unwrapped_step(angle, self._angle)
        self._angle = angle
        self._fallen = balls_fell(pos_a, pos_b)
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
            "turns": (self._turned / (2 * math.pi)).float().unsqueeze(-1),
        }

    def physical_metrics(self, final: dict[str, torch.Tensor]) -> dict[str, float]:
        """``rotations_per_10s`` as the base class's, and ``turns_per_10s``: the mean over episodes of
        each episode's turns taken without their sign (a policy may turn either way), per 10 s."""
        metrics = super().physical_metrics(final)
        if "turns" in final:
            metrics["turns_per_10s"] = (
                float(final["turns"].double().abs().mean()) * 10.0 / self.episode_seconds
            )
        return metrics
