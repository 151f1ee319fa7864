"""Moved: TD3's own training methods, :class:`GaussianActionNoise` and :class:`PolyakTarget`, are in
:mod:`ilcsan.rl.algorithms.td3`, beside the algorithm they belong to; this module keeps the old import path working."""

from __future__ import annotations

import warnings

from ..algorithms.td3 import GaussianActionNoise, PolyakTarget

__all__ = ["GaussianActionNoise", "PolyakTarget"]

warnings.warn("ilcsan.rl.methods.td3_own is deprecated: import GaussianActionNoise and PolyakTarget from "
              "ilcsan.rl.algorithms.td3", DeprecationWarning, stacklevel=2)
