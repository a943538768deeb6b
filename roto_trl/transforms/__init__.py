"""TorchRL transforms that turn a RoTO env's raw readings into the agent's inputs."""

from roto_trl.transforms.contacts import BinariseContacts
from roto_trl.transforms.proprioception import LastAction, ScaleProprioception

__all__ = ["BinariseContacts", "LastAction", "ScaleProprioception"]
