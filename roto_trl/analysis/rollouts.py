"""Deterministic episodes of a trained agent with everything the analyses read: latents, states,
contacts, actions and the encoder's inputs, step by step."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase

from roto_trl.modules.agent import Agent
from roto_trl.trainers.builders import make_eval_env
from roto_trl.trainers.checkpoint import agent_from_checkpoint
from roto_trl.trainers.evaluation import run_episodes


@dataclass
class Trajectories:
    """One episode per world, step-major (T steps, E worlds).

    Attributes:
        z: ``[T, E, 256]`` the encoder's latent of each step's observation.
        state: ``[T, E, S]`` the privileged physical state (ball pose and velocity, ...).
        contacts: ``[T, E, C]`` 0/1, the current tactile reading (the newest of the frame history).
        inputs: ``[T, E]`` the encoder's observation entries and the ``action`` taken.
        live: ``[T, E]`` bool, the step belongs to the world's first episode.
        state_names: the name of each state element (the task's ``STATE_NAMES``).
    """

    z: torch.Tensor
    state: torch.Tensor
    contacts: torch.Tensor
    inputs: TensorDict
    live: torch.Tensor
    state_names: tuple[str, ...]


def collect(
    state: dict[str, Any], worlds: int, seed: int, max_steps: int | None = None
) -> tuple[Agent, Trajectories]:
    """Run a checkpoint's deterministic policy for one episode in each of ``worlds`` fresh worlds.

    Args:
        state: a loaded training checkpoint (``roto_trl.trainers.checkpoint.load_checkpoint``).
        worlds: evaluation worlds (E).
        seed: the evaluation seed.
        max_steps: stop after this many steps (default: until every episode ended).

    Returns:
        The checkpoint's agent and the trajectories.
    """
    cfg = state["config"].copy()
    cfg.device = "cpu"
    env = make_eval_env(cfg, worlds)
    z, states, contacts, inputs, live = [], [], [], [], []
    try:
        agent = agent_from_checkpoint(state, env)
        n_contacts, state_names = len(env.base_env.SENSORS), env.base_env.STATE_NAMES

        def record(obs: TensorDictBase, decision: TensorDictBase, alive: torch.Tensor) -> None:
            z.append(decision["z"])
            states.append(obs["state"].clone())
            contacts.append(obs["tactile"][:, -n_contacts:].clone())
            inputs.append(decision.select(*agent.obs_keys, "action"))
            live.append(alive)

        run_episodes(env, agent, seed, on_step=record, max_steps=max_steps)
    finally:
        env.close()
    return agent, Trajectories(
        torch.stack(z),
        torch.stack(states),
        torch.stack(contacts),
        torch.stack(inputs),
        torch.stack(live),
        state_names,
    )
