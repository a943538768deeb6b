"""Data stores of training beyond TorchRL's own: the separated auxiliary memory."""

from roto_trl.data.memory import AuxMemory

__all__ = ["AuxMemory"]
