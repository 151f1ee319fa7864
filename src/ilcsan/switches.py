"""The names of every actor switch value, in one torch-free place (grids and the CLI validate with them)."""

from __future__ import annotations

PRESETS: tuple[str, ...] = ("ilc-san", "popsan", "mdc-san", "akl", "dan")
ENCODERS: tuple[str, ...] = ("pop-det", "pop-prob", "pop", "layer", "two-neuron")
SPIKING_ENCODERS: tuple[str, ...] = ("pop-det", "pop-prob")
DECODERS: tuple[str, ...] = ("last", "max", "mean", "fr")
INTRA_VARIANTS: tuple[str, ...] = ("intra", "self", "lateral", "bias", "lateral+bias", "self+bias", "self+lateral",
                                   "none")
NEURONS: tuple[str, ...] = ("clif", "dynamic")
NETWORKS: tuple[str, ...] = ("spiking", "deep")
