"""The ILC-SAN paper's choices, each its kind's default: TD3's Polyak-averaged target actor and Gaussian action
noise (Fujimoto et al. 2018), and no normalisation of the synaptic currents. Training: :mod:`ilcsan.rl.algorithms.td3`
(TD3's own methods, beside TD3) and :class:`ilcsan.rl.methods.Normalization`."""

from __future__ import annotations

from .declaration import Declared

DEFAULT_ALGORITHM = "td3"
"""The algorithm of a run, a grid row or a saved file that names none: TD3, the paper's
(:class:`~ilcsan.methods.td3.TD3Declaration`)."""
NO_NORMALIZATION = "none"
"""The normalisation that leaves the synaptic currents as they are, the paper's (:class:`NoNormalizationDeclaration`);
an exported actor's, its normalisation folded into the weights."""


class PolyakTargetDeclaration(Declared):
    kind, name, title = "target_actor", "polyak", "the Polyak-averaged target actor"
    paper = "the Polyak-averaged (soft-updated) copy of the actor (TD3, Fujimoto et al. 2018; the ILC-SAN paper)"
    option_help = "polyak, the Polyak-averaged copy of the actor (the paper)"
    renamed = ("spiking",)
    training = "ilcsan.rl.algorithms.td3:PolyakTarget"


class GaussianActionNoiseDeclaration(Declared):
    kind, name, title = "exploration", "gaussian", "Gaussian action noise"
    paper = "Gaussian noise on the action (TD3, Fujimoto et al. 2018; the ILC-SAN paper)"
    option_help = "TD3's Gaussian action noise (the paper)"
    training = "ilcsan.rl.algorithms.td3:GaussianActionNoise"


class NoNormalizationDeclaration(Declared):
    kind, name, title = "normalization", NO_NORMALIZATION, "no normalisation"
    paper = "the synaptic current W S + b reaches the neurons as it is (the ILC-SAN paper)"
    option_help = "none (the paper)"
    training = "ilcsan.rl.methods.base:Normalization"
