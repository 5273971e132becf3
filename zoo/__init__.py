"""OvertakeZoo deciders: each maps observations to modes and drives through the shared planner.

The package face: the decider protocol and the registry (:mod:`.base`). The members themselves are
in :mod:`.members` (numpy only), their trainers in :mod:`.train` (torch), the conformance check
for your own decider in :mod:`.testing`.
"""

from overtakezoo.zoo.base import (
    KINDS,
    ConstantDecider,
    Decider,
    Member,
    ObservationError,
    UnknownDecider,
    known_names,
    load,
    member,
    names,
    register,
)

__all__ = [
    "KINDS",
    "ConstantDecider",
    "Decider",
    "Member",
    "ObservationError",
    "UnknownDecider",
    "known_names",
    "load",
    "member",
    "names",
    "register",
]
