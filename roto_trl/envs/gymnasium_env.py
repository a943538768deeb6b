"""Gymnasium interface to the RoTO tasks, for researchers on other stacks.

``import roto_trl`` registers three ids (``roto_trl.envs.registration``); nothing else happens on import:

    envs = gymnasium.make_vec("RoTO/Bounce-v0", num_envs=1024)   # RoToVectorEnv, same-step autoreset
    env = gymnasium.make("RoTO/Find-v0")                         # RoToEnv, a single world

Both run the same batched MuJoCo core and observation pipeline as ``roto_trl.make_env`` (keyword
arguments other than ``num_envs``/``seed`` are ``make_env`` overrides, e.g. ``action_ema=0.5``).
Observations are a ``Dict`` of two ``Box`` spaces, ``prop`` and ``tactile`` (float32, the k-step
history, oldest reading first); actions a ``Box`` in [-1, 1]. ``info`` holds the task's episode
metrics (``bounces``, ``rotations``, ``object_distance``, ``find_time``), each reward term as
``reward/<term>`` and the privileged ``state``, one row per env.

The vector env autoresets in the same step (``AutoresetMode.SAME_STEP``): where an episode ended,
``step`` returns the first observation of the next one, and ``info["final_obs"]`` /
``info["final_info"]`` hold the last observation and info of the ended episode (``None`` for
envs that did not end), as Stable-Baselines3-style loops expect.
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from tensordict import TensorDictBase

from roto_trl.envs.factory import make_env

OBS_KEYS = ("prop", "tactile")


def _observation_space(td: TensorDictBase) -> spaces.Dict:
    """The ``Dict`` space of one env's observation, from a batched output ``td``."""
    return spaces.Dict(
        {
            "prop": spaces.Box(-np.inf, np.inf, shape=td["prop"].shape[1:], dtype=np.float32),
            "tactile": spaces.Box(0.0, 1.0, shape=td["tactile"].shape[1:], dtype=np.float32),
        }
    )


def check_reset_arguments(seed, options) -> None:
    """One-line errors for ``reset``'s arguments: ``seed`` None or an integer >= 0, ``options``
    None or a dict (the RoTO envs read no option; a dict of them is accepted as Gymnasium asks)."""
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0):
        raise ValueError(f"reset(seed=...) must be None or an integer >= 0, got {seed!r}")
    if options is not None and not isinstance(options, dict):
        raise ValueError(f"reset(options=...) must be None or a dict, got {options!r}")


def _open(task: str, num_envs: int, seed: int, overrides: dict):
    """The batched env, its first output, one env's observation space and action space."""
    env = make_env(task, num_envs, seed=seed, **overrides)
    td = env.reset()
    action_space = spaces.Box(-1.0, 1.0, shape=(env.base_env.n_actions,), dtype=np.float32)
    return env, td, _observation_space(td), action_space


def _obs(td: TensorDictBase) -> dict[str, np.ndarray]:
    # copies: the arrays handed out must not change when the env steps again
    return {key: td[key].detach().cpu().numpy().copy() for key in OBS_KEYS}


def _info(td: TensorDictBase, metrics: tuple[str, ...]) -> dict[str, np.ndarray]:
    info = {}
    for key in metrics:
        value = td[key].detach().cpu().numpy().copy()
        info[key] = value[:, 0] if value.shape[1] == 1 else value
    for term, value in td["reward_terms"].items():
        info[f"reward/{term}"] = value.detach().cpu().numpy()[:, 0].copy()
    info["state"] = td["state"].detach().cpu().numpy().copy()
    return info


def _actions(actions: Any, shape: tuple[int, int]) -> torch.Tensor:
    array = np.asarray(actions, dtype=np.float32)
    if array.shape != shape:
        raise ValueError(f"actions have shape {list(array.shape)}, expected {list(shape)}")
    return torch.from_numpy(array.copy())


class RoToVectorEnv(VectorEnv):
    """``num_envs`` worlds of a RoTO task as a Gymnasium ``VectorEnv`` (same-step autoreset).

    Args:
        task: ``"find"``, ``"bounce"`` or ``"baoding"``.
        num_envs: worlds stepped together.
        seed: seed of the reset randomisation (``reset(seed=...)`` reseeds).
        render_mode: ``None`` or ``"rgb_array"`` (``render()`` returns world 0's frame).
        **overrides: ``make_env`` overrides.
    """

    metadata: ClassVar[dict] = {
        "autoreset_mode": AutoresetMode.SAME_STEP,
        "render_modes": ["rgb_array"],
        "render_fps": 60,
    }

    def __init__(
        self, task: str, num_envs: int = 1, seed: int = 0, render_mode: str | None = None, **overrides
    ) -> None:
        self.env, self._td, self.single_observation_space, self.single_action_space = _open(
            task, num_envs, seed, overrides
        )
        self.task = task
        self.num_envs = num_envs
        self.render_mode = render_mode
        self._metrics = self.env.base_env.METRICS
        self.observation_space = gymnasium.vector.utils.batch_space(self.single_observation_space, num_envs)
        self.action_space = gymnasium.vector.utils.batch_space(self.single_action_space, num_envs)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        check_reset_arguments(seed, options)
        if seed is not None:
            self.env.set_seed(int(seed))
        self._td = self.env.reset()
        return _obs(self._td), _info(self._td, self._metrics)

    def step(self, actions):
        self._td.set("action", _actions(actions, (self.num_envs, self.single_action_space.shape[0])))
        stepped, self._td = self.env.step_and_maybe_reset(self._td)
        out = stepped["next"]
        terminated = out["terminated"].numpy()[:, 0].copy()
        truncated = out["truncated"].numpy()[:, 0].copy()
        info = _info(out, self._metrics)
        done = terminated | truncated
        if done.any():
            # the ended episodes' last observation and info, then the new episodes' first ones
            final_obs = np.full(self.num_envs, None, dtype=object)
            final_info = np.full(self.num_envs, None, dtype=object)
            last = _obs(out)
            for i in np.flatnonzero(done):
                final_obs[i] = {key: value[i] for key, value in last.items()}
                final_info[i] = {key: value[i] for key, value in info.items()}
            info = _info(self._td, self._metrics) | {
                "final_obs": final_obs,
                "final_info": final_info,
                "_final_obs": done.copy(),
                "_final_info": done.copy(),
            }
        reward = out["reward"].numpy()[:, 0].astype(np.float64)
        return _obs(self._td), reward, terminated, truncated, info

    def render(self):
        return self.env.render(0) if self.render_mode == "rgb_array" else None

    def close_extras(self, **kwargs) -> None:
        self.env.close()


class RoToEnv(gymnasium.Env):
    """One world of a RoTO task as a Gymnasium ``Env``.

    As Gymnasium's env checker expects: an action has exactly the action space's shape, and
    stepping after ``terminated`` or ``truncated`` is an error until ``reset``.

    Args: as ``RoToVectorEnv`` without ``num_envs``.
    """

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 60}

    def __init__(self, task: str, seed: int = 0, render_mode: str | None = None, **overrides) -> None:
        self.env, self._td, self.observation_space, self.action_space = _open(task, 1, seed, overrides)
        self.render_mode = render_mode
        self._metrics = self.env.base_env.METRICS
        self._ended = False

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        check_reset_arguments(seed, options)
        super().reset(seed=seed)
        self._ended = False
        if seed is not None:
            self.env.set_seed(int(seed))
        self._td = self.env.reset()
        return self._unbatch(_obs(self._td)), self._unbatch(_info(self._td, self._metrics))

    def step(self, action):
        if self._ended:
            raise RuntimeError("the episode has ended (terminated or truncated); call reset() before step()")
        array = np.asarray(action, dtype=np.float32)
        if array.shape != self.action_space.shape:
            expected = list(self.action_space.shape)
            raise ValueError(f"action has shape {list(array.shape)}, expected {expected}")
        self._td.set("action", _actions(array[None], (1, self.action_space.shape[0])))
        out = self.env.step(self._td)["next"]
        self._td = out
        self._ended = bool(out["done"][0, 0])
        info = self._unbatch(_info(out, self._metrics))
        return (
            self._unbatch(_obs(out)),
            float(out["reward"][0, 0]),
            bool(out["terminated"][0, 0]),
            bool(out["truncated"][0, 0]),
            info,
        )

    @staticmethod
    def _unbatch(values: dict[str, np.ndarray]) -> dict[str, Any]:
        return {key: value[0] for key, value in values.items()}

    def render(self):
        return self.env.render(0) if self.render_mode == "rgb_array" else None

    def close(self) -> None:
        self.env.close()
