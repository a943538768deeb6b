"""The peers of ``train_throughput.py`` and ``learning_vs_peers.py``: skrl's and rsl_rl's PPO on
our Gymnasium interface (and ``rsl_rl_evaluate``, rsl_rl's deterministic controller scored as
ours is).

Each runs the experiment's task, worlds and PPO values (R, mb, le, lr, gamma, lambda, clips,
gradient clip) on ``gymnasium.make_vec("RoTO/<Task>-v0")`` and returns frames/s over
``iterations`` timed iterations after one warm-up. skrl runs our networks
(``roto_trl.modules.networks``: encoder 1024-512-256 with LayerNorm + ELU, tanh-mean Gaussian
policy head with state-independent log-std, value head); rsl_rl its own MLPs with our layer sizes
and ELU but no LayerNorm (its ``MLPModel`` has none), and, as the peer ``rsl_rl_ln``, the same
MLPs with a LayerNorm after every hidden layer as our encoder has (``LayerNormMLPModel``), so
that a difference between ours and rsl_rl can be told from the network's. Both give the critic
separate layers, sized as ``agent.critic_encoder_sizes`` when set. Imported only when the peer is
installed (``.[bench]``).
"""

from __future__ import annotations

import functools
import logging
import math
import time

import gymnasium
import numpy as np
import torch
from torch import nn

from roto_trl.envs.registration import ENV_IDS
from roto_trl.modules.agent import checked_critic_sizes
from roto_trl.modules.networks import ENCODER_SIZES, Encoder, PolicyHead, ValueHead


def _vec_env(cfg):
    overrides = dict(cfg.env.overrides or {})
    return gymnasium.make_vec(ENV_IDS[str(cfg.env.task)], num_envs=int(cfg.env.num_envs), **overrides)


def critic_sizes(cfg) -> tuple[int, ...]:
    """The critic's hidden layers, as our separate critic has them (``agent.critic_encoder_sizes``)."""
    return checked_critic_sizes(cfg.agent.critic_encoder_sizes, shared_encoder=False)


def skrl_fps(cfg, iterations: int) -> float:
    import skrl
    from skrl.agents.torch.ppo import PPO, PPO_CFG
    from skrl.envs.wrappers.torch import wrap_env
    from skrl.memories.torch import RandomMemory
    from skrl.models.torch import DeterministicMixin, GaussianMixin, Model

    class Policy(GaussianMixin, Model):
        def __init__(self, observation_space, action_space, device):
            Model.__init__(
                self, observation_space=observation_space, action_space=action_space, device=device
            )
            GaussianMixin.__init__(self, clip_actions=False)
            self.encoder = Encoder(self.num_observations)
            self.head = PolicyHead(self.encoder.latent_dim, self.num_actions)

        def compute(self, inputs, role=""):
            loc, scale = self.head(self.encoder(inputs["observations"]))
            return loc, {"log_std": scale.log()}

    class Value(DeterministicMixin, Model):
        def __init__(self, observation_space, action_space, device):
            Model.__init__(
                self, observation_space=observation_space, action_space=action_space, device=device
            )
            DeterministicMixin.__init__(self)
            self.encoder = Encoder(self.num_observations, critic_sizes(cfg))
            self.head = ValueHead(self.encoder.latent_dim)

        def compute(self, inputs, role=""):
            return self.head(self.encoder(inputs["observations"])), {}

    skrl.logger.setLevel(logging.WARNING)  # its INFO line per wrapped env would split the table
    env = wrap_env(_vec_env(cfg), wrapper="gymnasium")
    a = cfg.agent
    rollout = int(a.rollout_len)
    memory = RandomMemory(memory_size=rollout, num_envs=env.num_envs, device=env.device)
    models = {
        "policy": Policy(env.observation_space, env.action_space, env.device),
        "value": Value(env.observation_space, env.action_space, env.device),
    }
    ppo_cfg = PPO_CFG(
        rollouts=rollout,
        learning_epochs=int(a.epochs),
        mini_batches=int(a.minibatches),
        discount_factor=float(a.gamma),
        gae_lambda=float(a.lmbda),
        learning_rate=float(a.lr),
        grad_norm_clip=float(a.max_grad_norm),
        ratio_clip=float(a.clip_epsilon),
        value_clip=float(a.clip_value),
        entropy_loss_scale=float(a.entropy_coeff),
        value_loss_scale=float(a.critic_coeff),
    )
    ppo_cfg.experiment.write_interval = 0
    ppo_cfg.experiment.checkpoint_interval = 0
    agent = PPO(
        models=models,
        memory=memory,
        observation_space=env.observation_space,
        action_space=env.action_space,
        device=env.device,
        cfg=ppo_cfg,
    )
    agent.init()
    agent.enable_training_mode(True)  # as skrl's SequentialTrainer does: otherwise it never updates
    observations, _ = env.reset()
    elapsed, timestep = 0.0, 0
    for it in range(iterations + 1):
        start = time.perf_counter()
        for _ in range(rollout):
            agent.pre_interaction(timestep=timestep, timesteps=10**9)
            with torch.no_grad():
                actions, _ = agent.act(observations, None, timestep=timestep, timesteps=10**9)
                next_obs, rewards, terminated, truncated, infos = env.step(actions)
                agent.record_transition(
                    observations=observations,
                    states=None,
                    actions=actions,
                    rewards=rewards,
                    next_observations=next_obs,
                    next_states=None,
                    terminated=terminated,
                    truncated=truncated,
                    infos=infos,
                    timestep=timestep,
                    timesteps=10**9,
                )
            agent.post_interaction(timestep=timestep, timesteps=10**9)  # updates after R steps
            observations = next_obs
            timestep += 1
        if it > 0:
            elapsed += time.perf_counter() - start
    env.close()
    return iterations * rollout * int(cfg.env.num_envs) / elapsed


def layer_norm_mlp_model():
    """rsl_rl's ``MLPModel`` with ``nn.LayerNorm`` between every hidden ``Linear`` and its
    activation, as in our encoder (``roto_trl.modules.networks.mlp``); the output layer stays
    plain. A class to give rsl_rl as ``class_name`` (built on demand: rsl_rl is optional)."""
    from rsl_rl.models import MLPModel

    class LayerNormMLPModel(MLPModel):
        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            linears = [m for m in self.mlp if isinstance(m, nn.Linear)]
            layers = []
            for module in self.mlp:
                layers.append(module)
                if isinstance(module, nn.Linear) and module is not linears[-1]:
                    layers.append(nn.LayerNorm(module.out_features))
            self.mlp = nn.Sequential(*layers)

    return LayerNormMLPModel


def rsl_rl_runner(cfg, log_dir: str | None = None, layer_norm: bool = False):
    """rsl_rl's ``OnPolicyRunner`` on our Gymnasium vector env, with the experiment's values.

    Its MLPs have our layer sizes and ELU, with no LayerNorm unless ``layer_norm``
    (``layer_norm_mlp_model``); actor and critic are separate networks (rsl_rl's design). Returns
    the runner and its env, whose ``episodes`` list collects ``(frames so far, metric value)`` for
    every training episode that ends (the task's first metric: bounces, rotations, ...).
    """
    from rsl_rl.env import VecEnv
    from rsl_rl.runners import OnPolicyRunner
    from tensordict import TensorDict

    class GymnasiumVecEnv(VecEnv):
        """rsl_rl's environment interface over our Gymnasium vector env (numpy in and out)."""

        def __init__(self, envs):
            self.envs = envs
            self.num_envs = envs.num_envs
            self.num_actions = envs.action_space.shape[-1]
            self.max_episode_length = int(cfg.env.overrides.get("episode_steps", 600))
            self.episode_length_buf = torch.zeros(self.num_envs, dtype=torch.long)
            self.device, self.cfg = "cpu", {}
            self.metric = envs.unwrapped.env.base_env.METRICS[0]
            self.frames, self.episodes = 0, []
            self._obs = self._tensordict(envs.reset(seed=int(cfg.seed))[0])

        def _tensordict(self, obs) -> TensorDict:
            return TensorDict({"policy": flat_observation(obs)}, batch_size=[self.num_envs])

        def get_observations(self) -> TensorDict:
            return self._obs

        def step(self, actions):
            obs, reward, terminated, truncated, info = self.envs.step(actions.detach().numpy())
            self.frames += self.num_envs
            for ended in info.get("final_info", ()):
                if ended is not None:
                    self.episodes.append((self.frames, float(ended[self.metric])))
            self._obs = self._tensordict(obs)
            dones = torch.as_tensor(terminated | truncated)
            extras = {"time_outs": torch.as_tensor(truncated)}
            return self._obs, torch.as_tensor(reward).float(), dones, extras

    a = cfg.agent
    model = layer_norm_mlp_model() if layer_norm else "MLPModel"
    train_cfg = {
        "num_steps_per_env": int(a.rollout_len),
        "save_interval": 10**9,
        "obs_groups": {"actor": ["policy"], "critic": ["policy"]},
        "algorithm": {
            "class_name": "PPO",
            "num_learning_epochs": int(a.epochs),
            "num_mini_batches": int(a.minibatches),
            "clip_param": float(a.clip_epsilon),
            "gamma": float(a.gamma),
            "lam": float(a.lmbda),
            "value_loss_coef": float(a.critic_coeff),
            "entropy_coef": float(a.entropy_coeff),
            "learning_rate": float(a.lr),
            "max_grad_norm": float(a.max_grad_norm),
            "schedule": "fixed",
            "normalize_advantage_per_mini_batch": True,
        },
        "actor": {
            "class_name": model,
            "hidden_dims": list(ENCODER_SIZES),
            "activation": "elu",
            "distribution_cfg": {"class_name": "GaussianDistribution"},
        },
        "critic": {"class_name": model, "hidden_dims": list(critic_sizes(cfg)), "activation": "elu"},
    }
    env = GymnasiumVecEnv(_vec_env(cfg))
    return OnPolicyRunner(env, train_cfg, log_dir=log_dir, device="cpu"), env


def flat_observation(obs: dict) -> torch.Tensor:
    """Our Gymnasium observation (``prop``, ``tactile``: ``[E, ...]``) as the peers' flat input
    ``[E, D]`` float32."""
    return torch.cat([torch.as_tensor(obs[k]) for k in ("prop", "tactile")], dim=-1).float()


@torch.no_grad()
def rsl_rl_evaluate(cfg, runner, episodes: int, seed: int, action: str) -> dict[str, float]:
    """The task's physical metrics (``bounces_per_10s``, ...) of rsl_rl's trained policy: one
    episode in each of ``episodes`` fresh worlds of our Gymnasium env reset with ``seed``.

    ``action`` is the deterministic action: ``gaussian_mean`` (rsl_rl's inference output, clipped
    by the env) or ``applied_mean`` (E[clip(a)] under its Gaussian, our default:
    ``roto_trl.modules.distributions``). An episode's metrics are those of its first ending.
    """
    from tensordict import TensorDict

    from roto_trl.modules.distributions import DETERMINISTIC_ACTIONS, clipped_normal_mean

    if action not in DETERMINISTIC_ACTIONS:
        raise ValueError(f"action={action!r}: choose one of {DETERMINISTIC_ACTIONS}")
    policy = runner.get_inference_policy()
    envs = gymnasium.make_vec(ENV_IDS[str(cfg.env.task)], num_envs=episodes, **dict(cfg.env.overrides or {}))
    base = envs.unwrapped.env.base_env
    columns = base.metric_columns()
    final = {name: torch.full((episodes,), math.nan) for _, _, name in columns}
    ended = torch.zeros(episodes, dtype=torch.bool)
    obs, _ = envs.reset(seed=seed)
    with torch.random.fork_rng():  # the samples drawn for the std leave training's stream alone
        while not bool(ended.all()):
            td = TensorDict({"policy": flat_observation(obs)}, batch_size=[episodes])
            if action == "gaussian_mean":
                act = policy(td)
            else:
                policy(td, stochastic_output=True)  # sets the distribution's mean and std
                act = clipped_normal_mean(policy.output_mean, policy.output_std)
            obs, _, _, _, info = envs.step(act.numpy())
            for i, last in enumerate(info.get("final_info", ())):
                if last is None or ended[i]:
                    continue
                ended[i] = True
                for key, column, name in columns:
                    final[name][i] = float(np.atleast_1d(last[key])[column])
    envs.close()
    return base.physical_metrics(final)


def rsl_rl_fps(cfg, iterations: int, layer_norm: bool = False) -> float:
    """Frames/s of rsl_rl's PPO over ``iterations`` timed iterations after one warm-up."""
    runner, env = rsl_rl_runner(cfg, layer_norm=layer_norm)
    runner.learn(1)  # warm-up
    start = time.perf_counter()
    runner.learn(iterations)
    elapsed = time.perf_counter() - start
    env.envs.close()
    return iterations * int(cfg.agent.rollout_len) * env.num_envs / elapsed


PEERS = {  # name -> (the package it needs installed, its frames/s runner)
    "skrl": ("skrl", skrl_fps),
    "rsl_rl": ("rsl_rl", rsl_rl_fps),
    "rsl_rl_ln": ("rsl_rl", functools.partial(rsl_rl_fps, layer_norm=True)),
}
