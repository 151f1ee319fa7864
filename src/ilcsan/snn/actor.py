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

The actor knows no training method. What a method changes in it is given as objects: at build time the module class
of a normalisation (``normalization``, CaRe-BN's :class:`~ilcsan.snn.normalization.CareBatchNorm`; the class a
normalisation's declaration names, resolved by :func:`ilcsan.actors.build_actor`), with which each synaptic layer's
current W^l S + b^l is normalised before its neurons (on the output layer before the intra-layer current is added);
per pass a :class:`~ilcsan.snn.output.PassOptions`: perturbations of the neurons
(:class:`~ilcsan.snn.noise.NeuronNoise`), which statistics the normalisation uses, where to record them, and
whether to return the pre-tanh output too.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from ..compute.matmul import DEFAULT_MATMUL, MatmulPath
from ..config import ENGINES, INTRA_MASKS, ActorConfig
from ..errors import UserError
from .decoders import PopulationDecoder
from .encoders import Encoder
from .ensemble import EnsembleLinear, EnsembleMLP, seed_generators
from .intra import IntraLayerConnections
from .neurons import neuron_model
from .noise import NeuronNoise
from .normalization import LayerNormalizations, NormStatistics, checked_statistics
from .output import PLAIN_PASS, ActorOutput, PassOptions
from .reference import run_reference

ACTOR_SALT = 1


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
    """The spiking actor network of Fig. 2 with every ablation as a switch; ``normalization``, the module class that
    normalises one synaptic layer's current (None: none; the module docstring)."""

    def __init__(self, config: ActorConfig, state_dim: int, action_dim: int, action_scale: Sequence[float],
                 action_offset: Sequence[float], seeds: Sequence[int], engine: str = "fast",
                 matmul_path: MatmulPath = DEFAULT_MATMUL, normalization: type[nn.Module] | None = None):
        super().__init__(config, state_dim, action_dim, action_scale, action_offset, engine)
        ensemble = len(seeds)
        self.encoder = Encoder(config.encoder, ensemble, state_dim, config.population_in, config.timesteps,
                               threshold=config.enc_v_th)
        sizes = config.layer_sizes(state_dim, action_dim)
        self.layers = nn.ModuleList(EnsembleLinear(ensemble, a, b, matmul_path=matmul_path)
                                    for a, b in zip(sizes[:-1], sizes[1:], strict=True))
        mask = INTRA_MASKS[config.intra]
        self.intra = (IntraLayerConnections(ensemble, action_dim, config.population_out, mask,
                                            bias_at_first_step=config.intra_timing == "authors")
                      if any(mask) else None)
        self.decoder = PopulationDecoder(ensemble, action_dim, config.population_out, config.decoder,
                                         config.alpha_v_li)
        self.neuron = neuron_model(config)
        self.norms = (LayerNormalizations(normalization, ensemble, sizes[1:], config.v_th)
                      if normalization is not None else None)
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
        if self.norms is not None:
            self.norms.reset_parameters()

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
                       statistics: str | tuple[NormStatistics, ...]) -> tuple[torch.Tensor, NormStatistics | None]:
        """Synaptic layer ``index``'s currents (K, T, B, D) from its input ``values`` — spikes (K, T, B, D), or an
        analog input (K, B, D) the same at every step when ``constant`` — normalised under a checked ``statistics``
        choice (:func:`~ilcsan.snn.normalization.checked_statistics`), with the statistics used (None without
        normalisation)."""
        currents = self.layers[index](values)
        used = None
        if self.norms is not None:  # an analog input's (K, B, D) currents: the same statistics as their T copies
            used = self.norms.statistics_of(index, currents, statistics)
            currents = self.norms[index](currents, used)
        if constant:
            currents = currents.unsqueeze(1).expand(-1, self.config.timesteps, *currents.shape[1:])
        return currents, used

    def _run_layer_major(self, state: torch.Tensor, noise: NeuronNoise | None, membranes: bool,
                         statistics: str | tuple[NormStatistics, ...]) -> ActorOutput:
        encoded = self.encoder(state)
        values, constant = encoded.values, encoded.constant
        inputs, recorded, used = [], [] if membranes else None, []
        last = len(self.layers) - 1
        for index in range(len(self.layers)):
            inputs.append(values)
            currents, layer_statistics = self.layer_currents(index, values, constant, statistics)
            used.append(layer_statistics)
            if noise is not None:
                currents = currents + noise.charge[index]
            values = self.layer_spikes(currents, index == last, None if noise is None else noise.transmission[index],
                                       recorded if index == last else None)
            constant = False
        output, voltages = self.decoder(values, None if noise is None else noise.decoder)
        return ActorOutput(self.squash(output), tuple(inputs), values, voltages, output,
                           torch.stack(recorded, dim=1) if membranes else None,
                           tuple(used) if self.norms is not None else None)

    def run(self, state: torch.Tensor, engine: str | None = None, *, options: PassOptions = PLAIN_PASS,
            membranes: bool = False) -> ActorOutput:
        """Normalised state (K, B, N) → :class:`ActorOutput` under ``options`` (:class:`PassOptions`: the neurons'
        perturbation, the normalisation's statistics, returned in :attr:`ActorOutput.norm_statistics`, and appended to
        ``options.record`` if given); ``engine`` overrides :attr:`engine` for analysis; ``membranes`` records the
        output layer's potentials (:attr:`ActorOutput.membranes`, diagnostics)."""
        statistics = checked_statistics(self.norms, options.statistics)
        if checked_engine(engine or self.engine) == "reference":
            output = run_reference(self, state, options.noise, membranes, statistics)
        else:
            output = self._run_layer_major(state, options.noise, membranes, statistics)
        if options.record is not None:
            options.record.append(output.norm_statistics)
        return output

    def forward(self, state: torch.Tensor,
                options: PassOptions = PLAIN_PASS) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Normalised state (K, B, N) → action (K, B, M), deterministic unless ``options.noise`` is given; with
        ``options.preaction`` (action, pre-tanh output O (K, B, M)); the rest of ``options`` as for :meth:`run`."""
        output = self.run(state, options=options)
        return (output.action, output.readout) if options.preaction else output.action

    def noise_widths(self) -> tuple[int, ...]:
        """The widths D_l of the synaptic layers' outputs, whose neurons NoisySAN perturbs."""
        return tuple(layer.out_features for layer in self.layers)


class DeepActor(_Actor):
    """DAN, TD3's deep actor network: (N, 256, ReLU, 256, ReLU, M) then tanh and the action scale.

    It has one forward pass; ``engine`` is accepted so that every actor is built and run the same way.
    """

    def __init__(self, config: ActorConfig, state_dim: int, action_dim: int, action_scale: Sequence[float],
                 action_offset: Sequence[float], seeds: Sequence[int], engine: str = "fast",
                 matmul_path: MatmulPath = DEFAULT_MATMUL):
        super().__init__(config, state_dim, action_dim, action_scale, action_offset, engine)
        self.mlp = EnsembleMLP(len(seeds), config.layer_sizes(state_dim, action_dim), matmul_path)
        self.mlp.reset_parameters(seed_generators(seeds, ACTOR_SALT))

    def run(self, state: torch.Tensor, engine: str | None = None, *, options: PassOptions = PLAIN_PASS,
            membranes: bool = False) -> ActorOutput:
        checked_engine(engine or self.engine)
        output = self.mlp(state)
        return ActorOutput(self.squash(output), (state,), None, None, output)

    def forward(self, state: torch.Tensor,
                options: PassOptions = PLAIN_PASS) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """As :meth:`SpikingActor.forward`; DAN has no neurons to perturb nor currents to normalise (the methods that
        would ask refuse a deep actor: :func:`ilcsan.methods.check_run`), so only ``options.preaction`` applies."""
        output = self.mlp(state)
        return (self.squash(output), output) if options.preaction else self.squash(output)
