"""Actor networks: the spiking actor family (ILC-SAN and its baselines) and TD3's deep actor (DAN).

:class:`SpikingActor` is one mechanism with switches (:class:`~ilcsan.config.ActorConfig`): encoder,
neuron, depth, intra-layer mask, decoder statistic. Its forward pass is layer-major: each synaptic
layer's matmul W^l S^{l−1}_{1..T} + b^l runs over all T steps at once (an analog input's matmul once),
and only the neuron updates (Eq. (1)-(3)) and the output population's intra-layer recurrence (Eq. (10))
loop over t. Because layer l at step t depends only on layer l−1 at step t and its own earlier state,
this computes Algorithm 1 exactly; :mod:`ilcsan.snn.reference` runs Algorithm 1 literally, one time step
at a time, as the tested oracle (``engine="reference"``). Both engines call the same neuron step,
intra-layer module and decoder operations.

Every tensor has a leading ensemble dimension K (seeds trained together): observations (K, B, N) →
actions (K, B, M).

With a normalisation (``normalization="care-bn"``: :mod:`ilcsan.snn.normalization`, the layer its declaration in
:mod:`ilcsan.methods` names) each synaptic layer's current W^l S + b^l is normalised before its neurons (on the output
layer before the intra-layer current is added), with the running statistics by default or, for the actor's loss, the
batch's own (``norm_statistics`` of :meth:`SpikingActor.run`).
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Sequence

import torch
from torch import nn

from .. import methods
from ..compute.matmul import DEFAULT_MATMUL, MatmulPath
from ..config import ENGINES, INTRA_MASKS, ActorConfig
from ..errors import UserError
from .decoders import PopulationDecoder
from .encoders import Encoder
from .ensemble import EnsembleLinear, EnsembleMLP, seed_generators
from .intra import IntraLayerConnections
from .neurons import neuron_model
from .noise import NeuronNoise
from .normalization import NormStatistics, batch_statistics, pool_statistics
from .output import ActorOutput
from .reference import run_reference

ACTOR_SALT = 1


NormStatisticsChoice = str | Sequence[NormStatistics]
"""Which statistics a normalising actor's layers use (``norm_statistics``): "running" (the default), "batch" (each
layer its batch's own, pooled over the batch and the T steps), or a sequence of :class:`NormStatistics` for the first
layers, the layers after them using their batch's own ("batch" is the empty sequence)."""


def checked_engine(engine: str) -> str:
    """``engine`` if it is one of :data:`ilcsan.config.ENGINES`, else a :class:`UserError` naming the choices."""
    if engine not in ENGINES:
        raise UserError(f"--engine {engine!r} is not one of: {', '.join(ENGINES)}")
    return engine


class _Actor(nn.Module):
    """What every actor holds: its configuration, sizes, engine and the action scaling
    action = offset + scale · tanh(O), scale and offset from the task's Box bounds."""

    def __init__(self, config: ActorConfig, state_dim: int, action_dim: int, action_scale: Sequence[float],
                 action_offset: Sequence[float], engine: str):
        super().__init__()
        self.config, self.state_dim, self.action_dim = config, state_dim, action_dim
        self._engine = checked_engine(engine)
        # constants of the task, not state (the convention: :mod:`ilcsan.snn.ensemble`)
        self.register_buffer("action_scale", torch.as_tensor(action_scale, dtype=torch.float32), persistent=False)
        self.register_buffer("action_offset", torch.as_tensor(action_offset, dtype=torch.float32), persistent=False)

    @property
    def engine(self) -> str:
        """The forward pass :meth:`run` uses unless told otherwise: 'fast' or 'reference' (fixed at construction)."""
        return self._engine

    def squash(self, output: torch.Tensor) -> torch.Tensor:
        return self.action_offset + self.action_scale * torch.tanh(output)


class SpikingActor(_Actor):
    """The spiking actor network of Fig. 2 with every ablation as a switch."""

    def __init__(self, config: ActorConfig, state_dim: int, action_dim: int, action_scale: Sequence[float],
                 action_offset: Sequence[float], seeds: Sequence[int], engine: str = "fast",
                 matmul: MatmulPath = DEFAULT_MATMUL):
        super().__init__(config, state_dim, action_dim, action_scale, action_offset, engine)
        ensemble = len(seeds)
        self.encoder = Encoder(config.encoder, ensemble, state_dim, config.population_in, config.timesteps,
                               threshold=config.enc_v_th)
        sizes = config.layer_sizes(state_dim, action_dim)
        self.layers = nn.ModuleList(EnsembleLinear(ensemble, a, b, matmul=matmul)
                                    for a, b in zip(sizes[:-1], sizes[1:], strict=True))
        mask = INTRA_MASKS[config.intra]
        self.intra = (IntraLayerConnections(ensemble, action_dim, config.population_out, mask,
                                            bias_at_first_step=config.intra_timing == "authors")
                      if any(mask) else None)
        self.decoder = PopulationDecoder(ensemble, action_dim, config.population_out, config.decoder,
                                         config.alpha_v_li)
        self.neuron = neuron_model(config)
        norm = methods.declared("normalization", config.normalization).actor_layer_class()
        self.norms = nn.ModuleList(norm(ensemble, width, config.v_th) for width in sizes[1:]) if norm else None
        self.reset_parameters(seed_generators(seeds, ACTOR_SALT))

    def reset_parameters(self, generators: Sequence[torch.Generator]) -> None:
        """Initialise encoder, layers, intra-layer connections and decoder, in that order, per seed; CaRe-BN's γ, β
        and statistics take fixed values and draw nothing, so the other weights are those of the same actor without
        normalisation."""
        self.encoder.reset_parameters(generators)
        for layer in self.layers:
            layer.reset_parameters(generators)
        if self.intra is not None:
            self.intra.reset_parameters(generators)
        self.decoder.reset_parameters(generators)
        for norm in self.norms or ():
            norm.reset_parameters()

    def checked_norm_statistics(self, choice: NormStatisticsChoice) -> str | tuple[NormStatistics, ...]:
        """``choice`` (:data:`NormStatisticsChoice`) as "running" or a tuple of given statistics ("batch": ()),
        or a :class:`UserError` when it is not one or this actor does not normalise."""
        if isinstance(choice, str) and choice not in ("running", "batch"):
            raise UserError(f"norm_statistics {choice!r} is not one of: running, batch, or a sequence of statistics")
        if self.norms is None:
            if choice != "running":
                raise UserError("this actor does not normalise its currents (--normalization none): it has no "
                                "batch statistics to use")
            return "running"
        if choice == "running":
            return choice
        given = () if choice == "batch" else tuple(choice)
        if len(given) > len(self.layers):
            raise UserError(f"{len(given)} layers' statistics given, the actor has {len(self.layers)} layers")
        return given

    def norm_statistics_of(self, index: int, currents: torch.Tensor,
                           choice: str | tuple[NormStatistics, ...]) -> NormStatistics:
        """The statistics synaptic layer ``index`` normalises its ``currents`` with under a checked ``choice``
        (:meth:`checked_norm_statistics`): the running ones, the given ones, or the batch's own."""
        if choice == "running":
            return self.norms[index].running()
        return choice[index] if index < len(choice) else batch_statistics(currents)

    def layer_spikes(self, currents: torch.Tensor, output_layer: bool, transmission: torch.Tensor | None = None,
                     membranes: list[torch.Tensor] | None = None) -> torch.Tensor:
        """Neuron updates of one layer over T steps; currents (K, T, B, D) → spikes (K, T, B, D).

        On the output layer the intra-layer current I_t of Eq. (10) is added from t = 2 on (and b_intra at t = 1
        with the authors' timing, :meth:`~ilcsan.snn.intra.IntraLayerConnections.first_current`); every other
        layer (and an output layer without intra-layer connections) runs the neuron's fused T-step train
        when it has one. ``transmission`` (NoisySAN, :class:`~ilcsan.snn.noise.NeuronNoise`) is added to the
        spikes passed on, the intra-layer connections included. A ``membranes`` list receives the potential
        each step compares with the threshold (:attr:`ActorOutput.membranes`).
        """
        neuron = self.neuron
        intra = self.intra if output_layer else None
        if intra is None and neuron.train is not None and membranes is None:
            spikes = neuron.train(currents, neuron.params)
            return spikes if transmission is None else spikes + transmission
        state = neuron.initial_state(currents[:, 0], neuron.params)
        weight = intra.masked_weight() if intra is not None else None
        bias = intra.masked_bias() if intra is not None else None
        intra_current = intra.first_current(currents[:, 0], bias) if intra is not None else None
        spikes, timesteps = [], currents.shape[1]
        for t in range(timesteps):
            current = currents[:, t] if intra_current is None else currents[:, t] + intra_current
            if membranes is not None:
                membranes.append(neuron.membrane(current, state, neuron.params))
            step_spikes, state = neuron.step(current, state, neuron.params)
            if transmission is not None:
                step_spikes = step_spikes + transmission[:, t]
            spikes.append(step_spikes)
            if intra is not None and t < timesteps - 1:
                intra_current = intra(step_spikes, weight, bias)
        return torch.stack(spikes, dim=1)

    def layer_currents(self, index: int, values: torch.Tensor, constant: bool,
                       norm_statistics: str | tuple[NormStatistics, ...]) -> tuple[torch.Tensor, NormStatistics | None]:
        """Synaptic layer ``index``'s currents (K, T, B, D) from its input ``values`` — spikes (K, T, B, D), or an
        analog input (K, B, D) the same at every step when ``constant`` — normalised under a checked
        ``norm_statistics`` choice (CaRe-BN), with the statistics used (None without normalisation)."""
        currents = self.layers[index](values)
        used = None
        if self.norms is not None:  # an analog input's (K, B, D) currents: the same statistics as their T copies
            used = self.norm_statistics_of(index, currents, norm_statistics)
            currents = self.norms[index](currents, used)
        if constant:
            currents = currents.unsqueeze(1).expand(-1, self.config.timesteps, *currents.shape[1:])
        return currents, used

    def _run_layer_major(self, state: torch.Tensor, noise: NeuronNoise | None, membranes: bool,
                         norm_statistics: str | tuple[NormStatistics, ...]) -> ActorOutput:
        encoded = self.encoder(state)
        values, constant = encoded.values, encoded.constant
        inputs, recorded, used = [], [] if membranes else None, []
        last = len(self.layers) - 1
        for index in range(len(self.layers)):
            inputs.append(values)
            currents, statistics = self.layer_currents(index, values, constant, norm_statistics)
            used.append(statistics)
            if noise is not None:
                currents = currents + noise.charge[index]
            values = self.layer_spikes(currents, index == last, None if noise is None else noise.transmission[index],
                                       recorded if index == last else None)
            constant = False
        output, voltages = self.decoder(values, None if noise is None else noise.decoder)
        return ActorOutput(self.squash(output), tuple(inputs), values, voltages, output,
                           torch.stack(recorded, dim=1) if membranes else None,
                           tuple(used) if self.norms is not None else None)

    def run(self, state: torch.Tensor, engine: str | None = None, noise: NeuronNoise | None = None,
            membranes: bool = False, norm_statistics: NormStatisticsChoice = "running") -> ActorOutput:
        """Normalised state (K, B, N) → :class:`ActorOutput`; ``engine`` overrides :attr:`engine` for analysis;
        ``noise`` perturbs the neurons (NoisySAN exploration, training only; added after the normalisation);
        ``membranes`` records the output layer's potentials (:attr:`ActorOutput.membranes`, diagnostics);
        ``norm_statistics`` (CaRe-BN only, :data:`NormStatisticsChoice`) says which statistics normalise each layer,
        returned in :attr:`ActorOutput.norm_statistics`."""
        choice = self.checked_norm_statistics(norm_statistics)
        if checked_engine(engine or self.engine) == "reference":
            return run_reference(self, state, noise, membranes, choice)
        return self._run_layer_major(state, noise, membranes, choice)

    def forward(self, state: torch.Tensor, noise: NeuronNoise | None = None, with_preaction: bool = False,
                norm_statistics: NormStatisticsChoice = "running", used_statistics: list | None = None,
                ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Normalised state (K, B, N) → action (K, B, M); deterministic unless ``noise`` is given;
        ``with_preaction`` also returns the pre-tanh output O (K, B, M); ``norm_statistics`` as for :meth:`run`;
        a ``used_statistics`` list receives the statistics each layer normalised with
        (:attr:`ActorOutput.norm_statistics`: how the actor's loss hands its batch statistics to the Kalman update,
        since a functional call of the module reaches its forward only)."""
        output = self.run(state, noise=noise, norm_statistics=norm_statistics)
        if used_statistics is not None:
            used_statistics.append(output.norm_statistics)
        return (output.action, output.readout) if with_preaction else output.action

    # ------------------------------------------------------------------ CaRe-BN's running statistics
    def update_running_statistics_(self, statistics: Sequence[NormStatistics], samples: int) -> None:
        """Move each layer's running statistics toward the batch statistics of a pass over ``samples`` states
        (:attr:`ActorOutput.norm_statistics` of ``norm_statistics="batch"``) by CaRe-BN's Kalman-style gain
        (:func:`~ilcsan.snn.normalization.kalman_update`), in place."""
        for norm, batch in zip(self._norms(), statistics, strict=True):
            norm.kalman_update_(batch, samples)

    @torch.no_grad()
    def recalibrated_statistics(self, batches: Sequence[torch.Tensor]) -> tuple[NormStatistics, ...]:
        """The exact statistics of each layer's currents pooled over all ``batches`` of normalised states
        (K, B_i, N), layer by layer: layer l's currents over every batch are computed with layers 1..l−1 normalised
        by their recalibrated statistics, so it takes one pass over the batches per layer, and the pass for layer l
        stops at layer l's currents (the later layers, the intra-layer loop and the decoder do not run: 1 + 2 + … + L
        layer products instead of L²). The hidden layers' spikes are the fast engine's, equal to the reference
        engine's. The actor is unchanged (:meth:`set_running_statistics_` installs the result)."""
        self._norms()  # a UserError for an actor without normalisation
        found: list[NormStatistics] = []
        for index in range(len(self.layers)):
            parts = []
            for batch in batches:
                encoded = self.encoder(batch)
                values, constant = encoded.values, encoded.constant
                for before in range(index):
                    currents, _ = self.layer_currents(before, values, constant, tuple(found))
                    values, constant = self.layer_spikes(currents, output_layer=False), False
                parts.append(batch_statistics(self.layers[index](values)))
            found.append(pool_statistics(parts, [batch.shape[1] for batch in batches]))
        return tuple(found)

    def set_running_statistics_(self, statistics: Sequence[NormStatistics]) -> None:
        """Replace each layer's running μ̂, σ̂² (P_μ, P_σ² are kept), in place."""
        for norm, layer_statistics in zip(self._norms(), statistics, strict=True):
            norm.set_running_(layer_statistics)

    def running_statistics(self) -> list[torch.Tensor]:
        """The running μ̂, σ̂² buffers of every layer in order: the tensors besides the parameters that the target
        actor's Polyak average must follow (its P_μ, P_σ² are never read)."""
        return [tensor for norm in self._norms() for tensor in norm.running()]

    def _norms(self) -> nn.ModuleList:
        if self.norms is None:
            raise UserError("this actor does not normalise its currents (--normalization none)")
        return self.norms

    def noise_widths(self) -> tuple[int, ...]:
        """The widths D_l of the synaptic layers' outputs, whose neurons NoisySAN perturbs."""
        return tuple(layer.out_features for layer in self.layers)


class DeepActor(_Actor):
    """DAN, TD3's deep actor network: (N, 256, ReLU, 256, ReLU, M) then tanh and the action scale.

    It has one forward pass; ``engine`` is accepted so that every actor is built and run the same way.
    """

    def __init__(self, config: ActorConfig, state_dim: int, action_dim: int, action_scale: Sequence[float],
                 action_offset: Sequence[float], seeds: Sequence[int], engine: str = "fast",
                 matmul: MatmulPath = DEFAULT_MATMUL):
        super().__init__(config, state_dim, action_dim, action_scale, action_offset, engine)
        self.mlp = EnsembleMLP(len(seeds), config.layer_sizes(state_dim, action_dim), matmul)
        self.mlp.reset_parameters(seed_generators(seeds, ACTOR_SALT))

    def run(self, state: torch.Tensor, engine: str | None = None, membranes: bool = False) -> ActorOutput:
        checked_engine(engine or self.engine)
        output = self.mlp(state)
        return ActorOutput(self.squash(output), (state,), None, None, output)

    def forward(self, state: torch.Tensor,
                with_preaction: bool = False) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        output = self.mlp(state)
        return (self.squash(output), output) if with_preaction else self.squash(output)


def folded_actor(actor: SpikingActor) -> SpikingActor:
    """An equivalent copy of a CaRe-BN actor without normalisation: each layer's W, b replaced by the fold of its
    running statistics, γ and β (:func:`~ilcsan.snn.normalization.fold_into_linear`), its config's
    ``normalization`` "none". Acting with running statistics, it gives the same actions up to float rounding, with
    plain synaptic layers (additions only on spikes). ``actor`` is not changed."""
    norms = actor._norms()
    folded = copy.deepcopy(actor)
    with torch.no_grad():
        for layer, norm in zip(folded.layers, norms, strict=True):
            weight, bias = norm.folded(layer.weight, layer.bias)
            layer.weight.copy_(weight)
            layer.bias.copy_(bias)
    folded.norms = None
    folded.config = dataclasses.replace(actor.config, normalization="none")
    return folded


def build_actor(config: ActorConfig, state_dim: int, action_dim: int, action_scale: Sequence[float],
                action_offset: Sequence[float] | None = None, seeds: Sequence[int] = (0,),
                engine: str = "fast", matmul: MatmulPath = DEFAULT_MATMUL) -> SpikingActor | DeepActor:
    """The actor ``config`` describes, for K = len(seeds) seeds, each initialised from its seed; ``engine``
    ('fast' or 'reference', :data:`ilcsan.config.ENGINES`) is its forward pass, ``matmul`` where its products run."""
    action_offset = [0.0] * action_dim if action_offset is None else action_offset
    cls = DeepActor if config.network == "deep" else SpikingActor
    return cls(config, state_dim, action_dim, action_scale, action_offset, seeds, engine, matmul)
