"""OvertakeZoo deciders: each maps observations to modes and drives through the shared planner."""

from .base import ConstantDecider, Decider, ObservationError, UnknownDecider, known_names, load, names, register

__all__ = ["ConstantDecider", "Decider", "ObservationError", "UnknownDecider", "known_names", "load", "names", "register"]
