"""The actor a configuration describes: the network of :mod:`ilcsan.snn.actor`, with the parts that training methods
declare resolved here, so that the spiking actor itself knows no method.

A normalisation (``actor.normalization``) declares in :mod:`ilcsan.methods` the module class that normalises one
synaptic layer (:attr:`~ilcsan.methods.Declared.actor_layer`); the builder hands that class to the actor. Everything
that builds an actor — the training algorithms, a loaded policy, Proxy Target's proxy, the tests — builds it here.
"""

from __future__ import annotations

from collections.abc import Sequence

from . import methods
from .compute.matmul import DEFAULT_MATMUL, MatmulPath
from .config import ActorConfig
from .snn.actor import DeepActor, SpikingActor


def build_actor(config: ActorConfig, state_dim: int, action_dim: int, action_scale: Sequence[float],
                action_offset: Sequence[float] | None = None, seeds: Sequence[int] = (0,),
                engine: str = "fast", matmul_path: MatmulPath = DEFAULT_MATMUL) -> SpikingActor | DeepActor:
    """The actor ``config`` describes, for K = len(seeds) seeds, each initialised from its seed; ``engine``
    ('fast' or 'reference', :data:`ilcsan.config.ENGINES`) is its forward pass, ``matmul_path`` where its products
    run; a spiking actor's normalisation is the layer class its declaration names (None for ``none``)."""
    action_offset = [0.0] * action_dim if action_offset is None else action_offset
    if config.network == "deep":
        return DeepActor(config, state_dim, action_dim, action_scale, action_offset, seeds, engine, matmul_path)
    normalization = methods.declared("normalization", config.normalization).actor_layer_class()
    return SpikingActor(config, state_dim, action_dim, action_scale, action_offset, seeds, engine, matmul_path,
                        normalization)
