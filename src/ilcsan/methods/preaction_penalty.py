"""The pre-action penalty as declared: λ·mean(O²) of the actor's pre-tanh output O added to the actor's loss, whose
gradient 2λO does not vanish where tanh′(O) does, so that it pulls a saturated actor back into tanh's range. Not from
a paper: this package's remedy for the saturated start measured in docs/fidelity-hopper/. Training (every
algorithm): :mod:`ilcsan.rl.methods.preaction_penalty`."""

from __future__ import annotations

from dataclasses import dataclass

from ..settings import setting
from .declaration import Declared


class PreactionPenaltyDeclaration(Declared):
    kind, name, title = "loss_term", "preaction-penalty", "the pre-action penalty"
    paper = ("a penalty λ·mean(O²) on the actor's pre-tanh output O (SAC: the mean's) in the actor's loss, which "
             "pulls a saturated actor back into tanh's range (this package's remedy for the saturated start, "
             "docs/fidelity-hopper)")
    weight = "preaction_penalty"
    training = "ilcsan.rl.methods.preaction_penalty:PreactionPenalty"

    @dataclass(frozen=True)
    class Settings:
        preaction_penalty: float = setting(0.0, "weight λ of a penalty λ·mean(O²) on the actor's pre-tanh output O, "
                                                "added to the actor's loss (0: the paper; > 0 pulls a saturated actor "
                                                "back into tanh's range)", bounds="non-negative")
