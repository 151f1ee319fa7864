"""Deployment: the numpy-only additions-only runtime, the ``.npz`` bundle, NIR graphs, int8 weights.

``from ilcsan.deploy import DeployedActor`` needs numpy only: :mod:`ilcsan.deploy.runtime` is a folder of
numpy-only modules (it can be copied alone); :mod:`ilcsan.deploy.bundle`, :mod:`ilcsan.deploy.nir` and
:mod:`ilcsan.deploy.quantize` are imported only when used (the first two need torch).
"""

from .runtime import SCALE_SUFFIX, DeployedActor

__all__ = ["DeployedActor", "SCALE_SUFFIX"]
