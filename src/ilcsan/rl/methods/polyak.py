"""TD3's target actor (Fujimoto et al. 2018; the ILC-SAN paper): a copy of the actor that follows it slowly."""

from __future__ import annotations

import copy

from .base import MethodContext, TargetActor


class PolyakTarget(TargetActor):
    """π' is a copy of the actor made at the start, moved at every delayed step by θ' ← τθ + (1 − τ)θ'."""

    soft_update = True

    def __init__(self, context: MethodContext):
        self.module = copy.deepcopy(context.actor)
        self.module.requires_grad_(False)
