"""Additions-only runtime for a deployed spiking actor: numpy only, no PyTorch.

``DeployedActor.load("actor.npz").act(observation)`` runs the ``.npz`` bundle written by
:mod:`ilcsan.deploy.bundle` and returns the same action as ``ilcsan.load(run).predict(observation)``
(float rounding aside, tested to 1e-4). It proves the paper's "fully spiking" claim (Section III): every
synaptic operation is an **accumulate** of a weight selected by a 0/1 spike, never a multiply.

What runs where
---------------
Synaptic layers, event-driven (counted as SOP, Section V-F):

* FC1 … FC(L+1) (Algorithm 1, W^l S_t^{l-1}): at every step t, the rows of Wᵀ (outgoing weights) of
  the presynaptic neurons that spiked are selected and added into the layer's input current; silent
  neurons cost nothing. One spike = fan-out accumulates.
* Intra FC (Eq. (10), I_{t+1}^m = W_intra^m S_t^{L,m} + b_intra^m): a spike of output neuron q at
  t = 1..T−1 adds column q of W_intra^m onto its own population. A chip holds only the synapses the
  ablation mask keeps (full: P_out, ``self``: 1, ``lateral``: P_out − 1, ``bias``/``none``: 0 per spike)
  and that is what is counted; numpy adds the whole block-diagonal column (zeros elsewhere), because one
  vectorised add is cheaper here than a scatter. With float weights these rows are stacked under FC(L+1)'s
  and both run as one accumulate per step (the output layer's input and its own previous spikes are
  adjacent in the pipeline's spike history; b_intra joins the bias from t = 2 on).
* Group FC (population decoder, X_t^m = W_D^m S_t^{L,m} + b_D^m): a spike adds one weight into the LI
  neuron of its population (each spike selects its weight from a (T, P_out, M) table, added per population
  in neuron order; :func:`~.synapses.steps_accumulator`).

The layers run pipelined (:class:`~.pipeline.Workspace`): at tick τ layer l computes its step τ − l, so
the neuron updates of all active layers are one vector operation per tick; the result is Algorithm 1's.
Buffers are preallocated per actor: use one :class:`DeployedActor` per thread.

Neuron-local state updates (the neuron core's work, not synaptic operations; no spike multiplies a
weight): the CLIF (or MDC-SAN dynamic) neuron's decay, threshold and hard reset, the constant biases
b^l, b_intra, b_D injected as currents, and the LI neuron V_t = α_V^LI V_{t−1} + X_t (Eq. (7)).

Host (dense floating point, no NIR/neuromorphic primitive, as in the paper): the frozen observation
normaliser clip((s − mean)/std, ±clip); the Gaussian receptive fields A = exp(−½((s−μ)/σ)²) (Eq. (9));
the encoder's deterministic soft-reset IF neurons (v ← v + A; S = [v > 0.999]; v ← v − 0.999·S);
the statistic O = Stat(V_1..V_T) (``last``/``max``/``mean``, Eq. (8)); and action = offset +
scale·tanh(O).

Counting
--------
``last_sop`` is the exact number of accumulates of the last inference (the sum over layers of
spikes × fan-out; ``last_sop_by_layer`` splits it with the layer names of
:mod:`ilcsan.analysis.energy`);
``total_sop``, ``total_sop_by_layer`` and ``inferences`` add up over calls. Bias currents are not
counted (a bias is a constant per-neuron current, not a synaptic event; the paper does not count it
either). Averaged over the same observations this equals the energy model's T·fr·Din·Dout exactly.

int8 bundles
------------
A bundle written with ``--weights int8`` (:mod:`ilcsan.deploy.quantize`) stores every synaptic weight matrix
as int8 ``q`` with a float32 per-layer scale ``s`` (array ``<name>.scale``), W ≈ s·q. The runtime
accumulates the integers exactly (int32 for the backbone and intra rows, exact integer-valued float64
bins for the decoder) and multiplies the integer sum by ``s`` once per neuron and step, as a chip's
neuron core would (integer synapses, one scale per layer); biases stay float32.

Scope and refusals
------------------
Fully spiking actors only: encoder ``pop-det``, neurons ``clif`` or ``dynamic``, decoders ``last``,
``max``, ``mean`` with any α_V^LI, every intra-layer mask, 1-4 hidden layers (any widths). Refused with
:class:`UserError`: ``pop-prob`` (stochastic Bernoulli encoding; the runtime is deterministic, re-train
or fine-tune with ``pop-det``), analog encoders ``pop``/``layer``/``two-neuron`` and the firing-rate
decoder ``fr`` (floating-point matrix operations: not fully spiking), deep actors (DAN), and a
non-zero reset voltage.

Modules
-------
:mod:`.actor` (:class:`DeployedActor`), :mod:`.pipeline` (the ticks of the backbone), :mod:`.synapses`
(event-driven accumulation), :mod:`.neurons` (CLIF and dynamic neuron updates), :mod:`.host` (normaliser,
encoders, statistic, action scaling; also used by the NIR host path), :mod:`.bundle_format` (metadata
keys, checks, reading the arrays), :mod:`.errors`.

Standalone use
--------------
This folder depends on numpy and the standard library only. Copy the folder next to a robot program
(under any name, e.g. ``deployed_actor/``) and ``from deployed_actor import DeployedActor``; inside the
package it raises :class:`ilcsan.errors.UserError`, standalone an equivalent local class.
"""

from .actor import DeployedActor
from .bundle_format import CONFIG_META_KEYS, SCALE_SUFFIX
from .errors import UserError

__all__ = ["CONFIG_META_KEYS", "DeployedActor", "SCALE_SUFFIX", "UserError"]
