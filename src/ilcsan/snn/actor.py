"""Actor networks: the spiking actor family (ILC-SAN and its baselines) and TD3's deep actor (DAN).

:class:`SpikingActor` is one mechanism with switches (:class:`~ilcsan.config.ActorConfig`): encoder,
neuron, depth, intra-layer mask, decoder statistic. It has two engines that compute the same function:

* ``reference``: Algorithm 1 literally — for t = 1..T, for l = 1..L, update layer l at step t, then the
  intra-layer current for t + 1 and the decoder's LI neuron.
* ``fast`` (default): layer-major — each synaptic layer's matmul runs over all T steps at once (an analog
  input's matmul once), and only the neuron updates and the output population's intra-layer recurrence
  loop over t. Equal to the reference up to float rounding (tested).

Every tensor has a leading ensemble dimension K (seeds trained together): observations (K, B, N) →
actions (K, B, M).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import torch
from torch import nn

from ..config import INTRA_MASKS, ActorConfig
from .decoders import PopulationDecoder, select_statistic
from .encoders import Encoder
from .ensemble import EnsembleLinear, EnsembleMLP, seed_generators
from .intra import IntraLayerConnections
from .neurons import (
    CLIFParams,
    DynamicParams,
    clif_initial_state,
    clif_step,
    clif_train,
    dynamic_initial_state,
    dynamic_step,
    li_step,
)

ACTOR_SALT = 1


class ActorOutput(NamedTuple):
    """Everything one forward pass produced.

    ``layer_inputs[l]`` is what synaptic layer l received: (K, T, B, D) spikes, or (K, B, D) for an
    analog input that is the same at every step. ``output_spikes`` (K, T, B, M·P_out) feeds the decoder
    (and the intra-layer connections at steps 1..T−1). ``voltages`` are the LI voltages (K, T, B, M).
    """

    action: torch.Tensor
    layer_inputs: tuple[torch.Tensor, ...]
    output_spikes: torch.Tensor | None
    voltages: torch.Tensor | None


class _Neuron(NamedTuple):
    step: object
    initial_state: object
    params: object
    train: object = None  # all T steps of a layer at once, with a written-out backward (CLIF only)


def _neuron(config: ActorConfig) -> _Neuron:
    if config.neuron == "dynamic":
        return _Neuron(dynamic_step, dynamic_initial_state,
                       DynamicParams(alpha_current=config.alpha_c, threshold=config.v_th,
                                     surrogate_width=config.surrogate_width))
    return _Neuron(clif_step, clif_initial_state,
                   CLIFParams(config.alpha_c, config.alpha_v, config.v_th, 0.0, config.surrogate_width), clif_train)


class _ActionScaling(nn.Module):
    """action = offset + scale · tanh(O), scale and offset from the task's Box bounds."""

    def __init__(self, action_scale: Sequence[float], action_offset: Sequence[float]):
        super().__init__()
        self.register_buffer("action_scale", torch.as_tensor(action_scale, dtype=torch.float32))
        self.register_buffer("action_offset", torch.as_tensor(action_offset, dtype=torch.float32))

    def squash(self, output: torch.Tensor) -> torch.Tensor:
        return self.action_offset + self.action_scale * torch.tanh(output)


class SpikingActor(_ActionScaling):
    """The spiking actor network of Fig. 2 with every ablation as a switch."""

    def __init__(self, config: ActorConfig, state_dim: int, action_dim: int,
                 action_scale: Sequence[float], action_offset: Sequence[float], seeds: Sequence[int]):
        super().__init__(action_scale, action_offset)
        self.config, self.state_dim, self.action_dim = config, state_dim, action_dim
        self.engine = "fast"
        ensemble = len(seeds)
        self.encoder = Encoder(config.encoder, ensemble, state_dim, config.population_in, config.timesteps,
                               threshold=config.enc_v_th)
        output_neurons = action_dim * config.population_out
        sizes = [self.encoder.output_dim, *config.hidden, output_neurons]
        self.layers = nn.ModuleList(EnsembleLinear(ensemble, a, b) for a, b in zip(sizes[:-1], sizes[1:],
                                                                                   strict=True))
        mask = INTRA_MASKS[config.intra]
        self.intra = (IntraLayerConnections(ensemble, action_dim, config.population_out, mask)
                      if any(mask) else None)
        self.decoder = PopulationDecoder(ensemble, action_dim, config.population_out, config.decoder,
                                         config.alpha_v_li)
        self.neuron = _neuron(config)
        self.reset_parameters(seed_generators(seeds, ACTOR_SALT))

    def reset_parameters(self, generators: Sequence[torch.Generator]) -> None:
        """Initialise encoder, layers, intra-layer connections and decoder, in that order, per seed."""
        self.encoder.reset_parameters(generators)
        for layer in self.layers:
            layer.reset_parameters(generators)
        if self.intra is not None:
            self.intra.reset_parameters(generators)
        self.decoder.reset_parameters(generators)

    # ------------------------------------------------------------------------------------ engines
    def _spiking_loop(self, currents: torch.Tensor, with_intra: bool) -> torch.Tensor:
        """Neuron updates of one layer over T steps; currents (K, T, B, D) → spikes (K, T, B, D).

        On the output layer the intra-layer current of step t (Eq. (10)) is added from t = 2 on.
        """
        step, params = self.neuron.step, self.neuron.params
        intra = self.intra if with_intra else None
        if intra is None and self.neuron.train is not None:
            return self.neuron.train(currents, params)
        state = self.neuron.initial_state(currents[:, 0], params)
        weight = intra.masked_weight() if intra is not None else None
        bias = intra.masked_bias() if intra is not None else None
        spikes, intra_current = [], None
        timesteps = currents.shape[1]
        for t in range(timesteps):
            current = currents[:, t] if intra_current is None else currents[:, t] + intra_current
            step_spikes, state = step(current, state, params)
            spikes.append(step_spikes)
            if intra is not None and t < timesteps - 1:
                intra_current = intra(step_spikes, weight, bias)
        return torch.stack(spikes, dim=1)

    def _run_fast(self, state: torch.Tensor) -> ActorOutput:
        encoded = self.encoder(state)
        values, constant = encoded.values, encoded.constant
        timesteps = self.config.timesteps
        inputs = []
        for index, layer in enumerate(self.layers):
            inputs.append(values)
            currents = layer(values)
            if constant:
                currents = currents.unsqueeze(1).expand(-1, timesteps, *currents.shape[1:])
            values = self._spiking_loop(currents, with_intra=index == len(self.layers) - 1)
            constant = False
        output, voltages = self.decoder(values)
        return ActorOutput(self.squash(output), tuple(inputs), values, voltages)

    def _run_reference(self, state: torch.Tensor) -> ActorOutput:
        """Algorithm 1, one time step at a time."""
        encoded = self.encoder(state)
        step, params = self.neuron.step, self.neuron.params
        last = len(self.layers) - 1
        timesteps = self.config.timesteps
        layer_states: list = [None] * len(self.layers)
        inputs: list[list[torch.Tensor]] = [[] for _ in self.layers]
        output_spikes, voltages = [], []
        intra_current = None
        voltage = None
        for t in range(timesteps):
            spikes = encoded.values if encoded.constant else encoded.values[:, t]
            for index, layer in enumerate(self.layers):
                inputs[index].append(spikes)
                current = layer(spikes)
                if index == last and intra_current is not None:
                    current = current + intra_current
                if layer_states[index] is None:
                    layer_states[index] = self.neuron.initial_state(current, params)
                spikes, layer_states[index] = step(current, layer_states[index], params)
            if self.intra is not None and t != timesteps - 1:
                intra_current = self.intra(spikes)
            output_spikes.append(spikes)
            if self.decoder.statistic != "fr":
                drive = self.decoder.group_fc(spikes)
                voltage = torch.zeros_like(drive) if voltage is None else voltage
                voltage = li_step(drive, voltage, self.decoder.alpha_voltage, self.decoder.reset)
                voltages.append(voltage)
        spike_train = torch.stack(output_spikes, dim=1)
        if self.decoder.statistic == "fr":
            output, voltage_trace = self.decoder(spike_train)
        else:
            voltage_trace = torch.stack(voltages, dim=1)
            output = select_statistic(voltage_trace, self.decoder.statistic)
        layer_inputs = tuple(
            per_layer[0] if (index == 0 and encoded.constant) else torch.stack(per_layer, dim=1)
            for index, per_layer in enumerate(inputs)
        )
        return ActorOutput(self.squash(output), layer_inputs, spike_train, voltage_trace)

    def run(self, state: torch.Tensor, engine: str | None = None) -> ActorOutput:
        """Normalised state (K, B, N) → :class:`ActorOutput`, with ``engine`` 'fast' or 'reference'."""
        engine = engine or self.engine
        return self._run_reference(state) if engine == "reference" else self._run_fast(state)

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        """Normalised state (K, B, N) → action (K, B, M)."""
        return self.run(state).action


class DeepActor(_ActionScaling):
    """DAN, TD3's deep actor network: (N, 256, ReLU, 256, ReLU, M) then tanh and the action scale."""

    def __init__(self, config: ActorConfig, state_dim: int, action_dim: int,
                 action_scale: Sequence[float], action_offset: Sequence[float], seeds: Sequence[int]):
        super().__init__(action_scale, action_offset)
        self.config, self.state_dim, self.action_dim = config, state_dim, action_dim
        self.engine = "fast"
        self.mlp = EnsembleMLP(len(seeds), [state_dim, *config.hidden, action_dim])
        self.mlp.reset_parameters(seed_generators(seeds, ACTOR_SALT))

    def run(self, state: torch.Tensor, engine: str | None = None) -> ActorOutput:
        return ActorOutput(self.squash(self.mlp(state)), (state,), None, None)

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        return self.squash(self.mlp(state))


def build_actor(config: ActorConfig, state_dim: int, action_dim: int, action_scale: Sequence[float],
                action_offset: Sequence[float] | None = None, seeds: Sequence[int] = (0,)) -> nn.Module:
    """The actor ``config`` describes, for K = len(seeds) seeds, each initialised from its seed."""
    action_offset = [0.0] * action_dim if action_offset is None else action_offset
    cls = DeepActor if config.network == "deep" else SpikingActor
    return cls(config, state_dim, action_dim, action_scale, action_offset, seeds)
