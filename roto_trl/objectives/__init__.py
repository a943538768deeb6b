"""Self-supervised objectives as TorchRL ``LossModule``s, each usable in any TorchRL project.

PPO itself is TorchRL's ``ClipPPOLoss`` (see ``roto_trl.trainers.builders.make_ppo_loss``).
"""

from roto_trl.objectives.forward_dynamics import ForwardDynamicsLoss, TactileForwardDynamicsLoss
from roto_trl.objectives.full_reconstruction import FullReconstructionLoss
from roto_trl.objectives.tactile_reconstruction import TactileReconstructionLoss

__all__ = [
    "ForwardDynamicsLoss",
    "FullReconstructionLoss",
    "TactileForwardDynamicsLoss",
    "TactileReconstructionLoss",
]
