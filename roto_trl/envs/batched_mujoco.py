"""A batch of MuJoCo worlds in one process, stepped in C on a persistent thread pool.

Why not ``torchrl.envs.custom.mujoco.MujocoEnv``: its backends batch through ``vmap``
(``mujoco-torch``, ``mjx``: fast on accelerators, slow on a 2-core CPU) or through one process per
env (``mujoco`` + ``ParallelEnv``). The fast CPU path is ``mujoco.rollout``: one call steps every
world for all substeps of a control step on C worker threads that release the GIL. This class
keeps ``MujocoEnv``'s subclass interface where it fits (``_sample_initial_state``,
``_prepare_ctrl``, ``_make_obs``, ``_compute_reward``, ``_compute_done``, ``_on_reset_mask``) and
runs it over ``mujoco.rollout``.

State lives in one ``[N, nstate]`` float64 array of MuJoCo's full physics state, plus the
positions of mocap bodies ``[N, nmocap, 3]`` (kinematic objects such as Find's fixed sphere: not
part of the physics state, so they travel with the controls). A control step:
``ctrl [N, nu]`` -> ``rollout(nstep=substeps)`` -> the last substep's state and the sensors of
every substep -> task hooks on torch tensors. The solver warm start is zeroed at the
start of every control step (``mujoco.rollout`` does so when given none), which makes a world's
result independent of the thread that stepped it: same seed and actions give the same numbers.
"""

from __future__ import annotations

import abc
import math
import os
from dataclasses import dataclass

import mujoco
import numpy as np
import torch
from mujoco import rollout as mj_rollout
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Bounded, Composite, Unbounded
from torchrl.envs import EnvBase

FULL_PHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS.value
CTRL = mujoco.mjtState.mjSTATE_CTRL.value
MOCAP_POS = mujoco.mjtState.mjSTATE_MOCAP_POS.value


def default_num_threads() -> int:
    """Worker threads for physics: the cores this process may run on."""
    return len(os.sched_getaffinity(0))


@dataclass
class PhysicsReading:
    """What one control step of physics returns, as torch tensors (float64, no copy of state).

    Attributes:
        qpos: ``[n, nq]`` joint positions after the last substep.
        qvel: ``[n, nv]`` joint velocities after the last substep.
        sensordata: ``[n, substeps, nsensordata]`` sensor values of every substep.
        mocap_pos: ``[n, nmocap, 3]`` positions of the mocap bodies.
    """

    qpos: torch.Tensor
    qvel: torch.Tensor
    sensordata: torch.Tensor
    mocap_pos: torch.Tensor


class BatchedMujocoEnv(EnvBase, abc.ABC):
    """TorchRL env over ``num_envs`` MuJoCo worlds stepped by ``mujoco.rollout``.

    Args:
        mj_model: the compiled model, its ``opt.timestep`` already set for ``substeps``.
        num_envs: number of worlds, the env's ``batch_size`` is ``[num_envs]``.
        substeps: physics steps per control step.
        max_episode_steps: control steps after which an episode is truncated.
        reward_scales: scale of each reward term the task computes; the reward is their sum.
        seed: seed of the reset randomisation.
        device: device of the returned tensors (physics always runs on the CPU).
        num_threads: physics worker threads (default: every core this process may use).
    """

    batch_locked = True

    def __init__(
        self,
        mj_model: mujoco.MjModel,
        num_envs: int,
        *,
        substeps: int,
        max_episode_steps: int,
        reward_scales: dict[str, float],
        seed: int = 0,
        device: str | torch.device = "cpu",
        num_threads: int | None = None,
    ) -> None:
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        super().__init__(device=device, batch_size=torch.Size([int(num_envs)]))
        self.mj_model = mj_model
        self.num_envs = int(num_envs)
        self.substeps = int(substeps)
        self.max_episode_steps = int(max_episode_steps)
        self.reward_scales = dict(reward_scales)
        self.num_threads = default_num_threads() if num_threads is None else int(num_threads)
        if self.num_threads < 1:
            raise ValueError(f"num_threads must be >= 1, got {num_threads}")

        m = mj_model
        self._pool = mj_rollout.Rollout(nthread=self.num_threads if self.num_threads > 1 else 0)
        self._datas = [mujoco.MjData(m) for _ in range(self.num_threads)]
        self._models = [m] * self.num_envs  # rollout wants one model pointer per world
        self.nstate = mujoco.mj_stateSize(m, FULL_PHYSICS)
        # Offsets of qpos / qvel inside a full-physics state vector: [time, qpos, qvel, ...].
        self._qpos_slice = slice(1, 1 + m.nq)
        self._qvel_slice = slice(1 + m.nq, 1 + m.nq + m.nv)
        template = mujoco.MjData(m)
        mujoco.mj_resetData(m, template)
        self._state0 = np.empty(self.nstate)
        mujoco.mj_getState(m, template, self._state0, FULL_PHYSICS)

        n = self.num_envs
        self._state = np.tile(self._state0, (n, 1))
        self._mocap0 = np.array(template.mocap_pos)
        self._mocap_pos = np.tile(self._mocap0, (n, 1, 1))
        # rollout's controls: ctrl, then the mocap positions when the model has mocap bodies
        self._control_spec = CTRL | (MOCAP_POS if m.nmocap else 0)
        self._ctrl = np.zeros((n, self.substeps, m.nu + 3 * m.nmocap))
        self._state_out = np.zeros((n, self.substeps, self.nstate))
        self._sensordata = np.zeros((n, self.substeps, m.nsensordata))
        self._step_count = torch.zeros(n, dtype=torch.long)
        # The reading is made of views of the buffers that steps and resets write in place, so it
        # is built once rather than at every step.
        state = torch.from_numpy(self._state)
        self._latest = PhysicsReading(
            qpos=state[:, self._qpos_slice],
            qvel=state[:, self._qvel_slice],
            sensordata=torch.from_numpy(self._sensordata),
            mocap_pos=torch.from_numpy(self._mocap_pos),
        )
        self.rng = np.random.default_rng(seed)
        self._closed = False
        self._make_specs()

    # ------------------------------------------------------------------ subclass interface

    @abc.abstractmethod
    def _make_obs_spec(self) -> dict:
        """Per-env observation entries, ``{key: spec}`` with the batch dimension included."""

    @abc.abstractmethod
    def _sample_initial_state(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return ``(qpos [n, nq], qvel [n, nv], ctrl [n, nu])`` for the envs ``idx`` that start.

        A task with mocap bodies also writes their start positions into ``self._mocap_pos[idx]``.
        """

    @abc.abstractmethod
    def _ctrl_for_state(self, idx: np.ndarray, qpos: np.ndarray) -> np.ndarray:
        """Initial ``ctrl [n, nu]`` that holds the given ``qpos [n, nq]`` of the envs ``idx``."""

    @abc.abstractmethod
    def _prepare_ctrl(self, action: torch.Tensor) -> np.ndarray:
        """Map a validated action ``[N, n_actions]`` to simulator ``ctrl`` ``[N, nu]`` (float64)."""

    @abc.abstractmethod
    def _make_obs(self, reading: PhysicsReading) -> dict[str, torch.Tensor]:
        """Observation entries for all envs from the latest physics reading."""

    @abc.abstractmethod
    def _compute_reward(self, reading: PhysicsReading) -> dict[str, torch.Tensor]:
        """Unscaled reward terms ``{name: [N]}`` (the keys of ``reward_scales``).

        Also advances the task's episode counters; the base class scales, sums and reports them
        as ``("reward_terms", name)`` so that each term can be logged as ``reward/<name>``.
        """

    @abc.abstractmethod
    def _compute_done(self, reading: PhysicsReading) -> torch.Tensor:
        """Termination flags ``[N]`` (bool)."""

    @abc.abstractmethod
    def _on_reset_mask(self, idx: np.ndarray) -> None:
        """Clear the task's per-episode state of the envs ``idx`` that start a new episode."""

    @property
    @abc.abstractmethod
    def n_actions(self) -> int:
        """Size of the action vector."""

    # ------------------------------------------------------------------ physics

    def _rollout(self, state, ctrl_buf, state_out, sensor_out) -> None:
        self._pool.rollout(
            self._models[: len(state)],
            self._datas,
            state,
            ctrl_buf,
            control_spec=self._control_spec,
            skip_checks=True,
            nstep=ctrl_buf.shape[1],
            state=state_out,
            sensordata=sensor_out,
        )

    def _physics(self, ctrl: np.ndarray) -> PhysicsReading:
        """Advance every world by one control step (``substeps`` physics steps) holding ``ctrl [N, nu]``."""
        self._ctrl[:, :, : self.mj_model.nu] = ctrl[:, None, :]
        self._rollout(self._state, self._ctrl, self._state_out, self._sensordata)
        self._state[:] = self._state_out[:, -1]
        return self._reading()

    def _settle(self, idx: np.ndarray, ctrl: np.ndarray) -> None:
        """One physics step of the worlds ``idx`` from their sampled state, holding ``ctrl [n, nu]``.

        MuJoCo computes contact forces inside a step, so this is what gives the first observation
        of an episode real contact readings (for one substep, broadcast over the reading's slots).
        """
        n, nu = len(idx), self.mj_model.nu
        state = np.ascontiguousarray(self._state[idx])
        controls = np.empty((n, 1, self._ctrl.shape[-1]))
        controls[:, 0, :nu] = ctrl
        controls[:, 0, nu:] = self._mocap_pos[idx].reshape(n, -1)
        # the step after the reset holds the new mocap positions too
        self._ctrl[idx, :, nu:] = controls[:, :, nu:]
        state_out = np.empty((n, 1, self.nstate))
        sensor_out = np.empty((n, 1, self.mj_model.nsensordata))
        self._rollout(state, controls, state_out, sensor_out)
        self._state[idx] = state_out[:, 0]
        self._sensordata[idx] = sensor_out

    def _reading(self) -> PhysicsReading:
        """The latest physics reading (views, always current: every step writes in place)."""
        return self._latest

    # ------------------------------------------------------------------ specs

    def _make_specs(self) -> None:
        n = self.num_envs
        term = Unbounded(shape=(n, 1), dtype=torch.float32, device=self.device)
        self.observation_spec = Composite(
            {
                **self._make_obs_spec(),
                "reward_terms": Composite(
                    {k: term.clone() for k in self.reward_scales}, shape=(n,), device=self.device
                ),
            },
            shape=(n,),
            device=self.device,
        )
        self.action_spec = Bounded(
            low=-1.0, high=1.0, shape=(n, self.n_actions), dtype=torch.float32, device=self.device
        )
        self.reward_spec = Unbounded(shape=(n, 1), dtype=torch.float32, device=self.device)

        flag = Binary(n=1, shape=(n, 1), dtype=torch.bool, device=self.device)
        self.full_done_spec = Composite(
            done=flag.clone(),
            terminated=flag.clone(),
            truncated=flag.clone(),
            shape=(n,),
            device=self.device,
        )

    # ------------------------------------------------------------------ EnvBase

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"this {type(self).__name__} is closed (close() was called); make a new env")

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        """Start new episodes: all envs, or those flagged in ``tensordict["_reset"]``.

        Keyword Args:
            qpos, qvel: optional ``[N, nq]`` / ``[N, nv]`` states to start from (rows of the
                envs that do not reset are ignored); default: the task's random initial state.
            mocap_pos: optional ``[N, nmocap, 3]`` positions of the mocap bodies, with ``qpos``.
        """
        self._check_open()
        mask = None if tensordict is None else tensordict.get("_reset", None)
        if mask is None or bool(mask.all()):
            idx = np.arange(self.num_envs)
        else:
            idx = np.flatnonzero(mask.reshape(self.num_envs).cpu().numpy())
        if len(idx):
            if kwargs.get("qpos") is not None:
                qpos, qvel = self._given_state(kwargs["qpos"], kwargs.get("qvel"), idx)
                ctrl = self._ctrl_for_state(idx, qpos)
                if kwargs.get("mocap_pos") is not None:
                    self._mocap_pos[idx] = self._given_mocap(kwargs["mocap_pos"], idx)
            else:
                qpos, qvel, ctrl = self._sample_initial_state(idx)
            self._state[idx] = self._state0
            self._state[idx, self._qpos_slice] = qpos
            self._state[idx, self._qvel_slice] = qvel
            self._step_count[idx] = 0
            self._on_reset_mask(idx)
            self._settle(idx, ctrl)
        obs = self._make_obs(self._reading())
        obs["reward_terms"] = {k: torch.zeros(self.num_envs, 1) for k in self.reward_scales}
        zeros = torch.zeros(self.num_envs, 1, dtype=torch.bool)
        return self._output({**obs, "done": zeros, "terminated": zeros.clone(), "truncated": zeros.clone()})

    def _output(self, entries: dict) -> TensorDictBase:
        """``entries`` (``[N, ...]`` CPU tensors, nested dicts allowed) as the env's output.

        On the CPU the tensordict is built without validating each entry, which the specs already
        guarantee (shape and dtype are fixed by construction): that check costs more per step than
        the tasks' own maths. On another device the entries are moved there.
        """
        if self.device.type == "cpu":
            return TensorDict._new_unsafe(entries, batch_size=self.batch_size, device=self.device)
        return TensorDict(entries, batch_size=self.batch_size, device=self.device)

    def _given_state(self, qpos: torch.Tensor, qvel: torch.Tensor | None, idx: np.ndarray):
        m, n = self.mj_model, self.num_envs
        qvel = torch.zeros(n, m.nv) if qvel is None else qvel
        if tuple(qpos.shape) != (n, m.nq) or tuple(qvel.shape) != (n, m.nv):
            raise ValueError(
                f"reset(qpos=, qvel=) expects qpos [{n}, {m.nq}] and qvel [{n}, {m.nv}], "
                f"got {list(qpos.shape)} and {list(qvel.shape)}"
            )
        return tuple(torch.as_tensor(x).detach().cpu().double().numpy()[idx] for x in (qpos, qvel))

    def _given_mocap(self, mocap_pos: torch.Tensor, idx: np.ndarray) -> np.ndarray:
        expected = (self.num_envs, self.mj_model.nmocap, 3)
        if tuple(mocap_pos.shape) != expected:
            raise ValueError(f"reset(mocap_pos=) expects shape {list(expected)}, got {list(mocap_pos.shape)}")
        return torch.as_tensor(mocap_pos).detach().cpu().double().numpy()[idx]

    def get_state(self) -> TensorDict:
        """A copy of the simulator state: ``qpos [N, nq]``, ``qvel [N, nv]``, ``mocap_pos [N, nmocap, 3]``.

        Edit it and pass it back as ``env.reset(td, qpos=..., qvel=..., mocap_pos=...)`` to start
        the envs that reset (all, or those flagged in ``td["_reset"]``) from that state instead of
        a random one (float64, metres and radians).
        """
        reading = self._reading()
        return TensorDict(
            {
                "qpos": reading.qpos.clone(),
                "qvel": reading.qvel.clone(),
                "mocap_pos": reading.mocap_pos.clone(),
            },
            batch_size=self.batch_size,
        )

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        self._check_open()
        action = self._validated_action(tensordict.get("action"))
        reading = self._physics(self._prepare_ctrl(action))
        self._step_count += 1
        terms = self._compute_reward(reading)
        terminated = self._compute_done(reading).reshape(self.num_envs, 1)
        truncated = (self._step_count >= self.max_episode_steps).reshape(self.num_envs, 1)
        obs = self._make_obs(reading)
        scaled = {k: (self.reward_scales[k] * terms[k]).to(torch.float32).reshape(-1, 1) for k in terms}
        obs["reward_terms"] = scaled
        obs["reward"] = sum(scaled.values())
        return self._output(
            {**obs, "done": terminated | truncated, "terminated": terminated, "truncated": truncated}
        )

    def _validated_action(self, action: torch.Tensor | None) -> torch.Tensor:
        """The action as float32 on the CPU, or a clear error; a non-finite value never passes."""
        expected = (self.num_envs, self.n_actions)
        if action is None:
            raise KeyError("the input tensordict has no 'action' entry")
        if tuple(action.shape) != expected:
            raise ValueError(
                f"action has shape {list(action.shape)} but this env expects {list(expected)} "
                f"(num_envs={self.num_envs}, n_actions={self.n_actions})"
            )
        action = action.detach().to("cpu", torch.float32)
        # A finite sum proves every entry finite and costs a fifth of isfinite().all(); a sum that
        # is not finite (NaN, inf or an overflow of huge values) gets the exact check.
        if not math.isfinite(float(action.sum())) and not bool(torch.isfinite(action).all()):
            bad = (~torch.isfinite(action)).any(-1).nonzero().flatten()[:8].tolist()
            raise ValueError(
                f"action contains NaN or inf (envs {bad}); the simulator was not stepped. "
                "Check the policy's outputs and losses for NaN"
            )
        return action

    def _set_seed(self, seed: int | None) -> None:
        self.rng = np.random.default_rng(seed)

    def close(self, *, raise_if_closed: bool = True) -> None:
        self._closed = True
        self._pool.close()
        super().close(raise_if_closed=raise_if_closed)
