"""RoTO-TRL's ForwardDynamicsLoss added to a stock TorchRL PPO on Pendulum (not a RoTO env).

python examples/ssl_with_torchrl_ppo.py
"""

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import GymEnv
from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss, SoftUpdate
from torchrl.objectives.value import GAE

from roto_trl.objectives import ForwardDynamicsLoss


def main(iterations: int = 10, frames: int = 512, seed: int = 0) -> list[dict[str, float]]:
    torch.manual_seed(seed)
    env = GymEnv("Pendulum-v1")
    env.set_seed(seed)
    encoder = TensorDictModule(nn.Sequential(nn.Linear(3, 64), nn.Tanh()), ["observation"], ["z"])
    head = TensorDictModule(nn.Sequential(nn.Linear(64, 2), NormalParamExtractor()), ["z"], ["loc", "scale"])
    policy = ProbabilisticActor(
        TensorDictSequential(encoder, head), ["loc", "scale"], distribution_class=TanhNormal,
        distribution_kwargs={"low": -2.0, "high": 2.0}, return_log_prob=True,
    )  # fmt: skip
    value = TensorDictSequential(encoder, ValueOperator(nn.Linear(64, 1), in_keys=["z"]))
    ppo, gae = ClipPPOLoss(policy, value), GAE(gamma=0.99, lmbda=0.95, value_network=value)
    fd = ForwardDynamicsLoss(encoder, action_dim=1, latent_dim=64)  # the line that adds SSL
    ema = SoftUpdate(fd, tau=0.01)
    params = {id(p): p for p in [*ppo.parameters(), *fd.parameters()]}.values()
    optimizer = torch.optim.Adam(params, lr=3e-4)
    history = []
    collector = Collector(env, policy, frames_per_batch=frames, total_frames=frames * iterations,
                          auto_register_policy_transforms=False)  # fmt: skip
    for batch in collector:
        gae(batch)
        same_episode = ~batch["next", "done"][:-1].squeeze(-1)  # pairs (t, t+1) of one episode
        pairs = torch.stack([batch[:-1], batch[1:]], dim=1)[same_episode]  # [B, n = 2]
        losses, aux = ppo(batch), fd(pairs)
        total = losses["loss_objective"] + losses["loss_critic"] + losses["loss_entropy"]
        total = total + 0.1 * aux["loss_dynamics"]
        optimizer.zero_grad()
        total.backward()
        optimizer.step()
        ema.step()
        fd_loss = float(aux["loss_dynamics"].detach())
        history.append({"reward": float(batch["next", "reward"].mean()), "fd": fd_loss})
        print(history[-1])
    return history


if __name__ == "__main__":
    main()
