"""Deployment: the ``.npz`` bundle, NIR graphs, int8 weights, the deployable ``Policy``; the numpy runtime they feed is
:mod:`ilcsan.runtime`.

``from ilcsan.deploy import DeployedActor`` needs numpy only: :mod:`ilcsan.runtime` is a folder of numpy-only modules
(it can be copied alone); :mod:`ilcsan.deploy.bundle`, :mod:`ilcsan.deploy.nir` and :mod:`ilcsan.deploy.quantize` are
imported only when used (the first two need torch).
"""

__all__ = ["DeployedActor", "SCALE_SUFFIX"]


def __getattr__(name: str):
    """``DeployedActor`` and ``SCALE_SUFFIX`` from :mod:`ilcsan.runtime`, imported on first use, so that importing a
    submodule (the CLI reads :mod:`.lava`'s options at start) does not import numpy."""
    if name in __all__:
        from .. import runtime

        return getattr(runtime, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
