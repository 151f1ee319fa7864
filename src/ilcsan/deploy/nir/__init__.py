"""NIR export of a spiking actor, the reference interpreter, the host side and loaders for NIR consumers.

``export_nir(policy, path)`` writes the graph (:mod:`.graph`: layout, CLIF → CubaLIF, dt = 1e-4 s);
``nir.read(path)`` gives it back; :func:`nir_action` runs it with :func:`simulate_nir` (:mod:`.interpreter`)
and the host parts (:mod:`.host`); :mod:`.consumers` loads it into snnTorch, Norse, SpikingJelly or (target
``sinabs``, :mod:`.sinabs`) Sinabs and runs it there.
"""

from .graph import DT, FORMAT, TARGETS, block_diagonal, build_graph, cubalif_parameters, export_nir, leaky_integrator
from .host import host_decode, host_encode, nir_action, read_host
from .interpreter import simulate_nir

__all__ = ["DT", "FORMAT", "TARGETS", "block_diagonal", "build_graph", "cubalif_parameters", "export_nir",
           "host_decode", "host_encode", "leaky_integrator", "nir_action", "read_host", "simulate_nir"]
