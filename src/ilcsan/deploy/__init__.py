"""Deployment: the numpy-only additions-only runtime, the ``.npz`` bundle, NIR graphs, int8 weights.

``from ilcsan.deploy import DeployedActor`` needs numpy only: this package imports nothing that needs
torch until :mod:`ilcsan.deploy.bundle` or :mod:`ilcsan.deploy.nir` is imported.
"""

from .runtime import SCALE_SUFFIX, DeployedActor

__all__ = ["DeployedActor", "SCALE_SUFFIX"]
