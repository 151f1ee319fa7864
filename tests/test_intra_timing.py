"""--intra-timing: b_intra from t = 2 (Algorithm 1) or from t = 1 (the authors' code), hand-computed at T = 2 and
equal in every place that runs an actor: both engines, the numpy runtime (float and int8), NIR and the energy model."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ilcsan.actors import build_actor
from ilcsan.analysis.energy import energy_report, measure_firing_rates
from ilcsan.config import actor_config
from ilcsan.deploy import DeployedActor
from ilcsan.deploy.bundle import bundle_arrays, bundle_meta
from ilcsan.deploy.nir import build_graph, simulate_nir
from ilcsan.deploy.policy import Policy
from ilcsan.deploy.quantize import quantize_bundle

# One output population of P = 2 CLIF neurons (α_C 0.5, α_V 0.75, V_th 0.5), T = 2, a constant feed-forward drive
# X = (0.3, 0) at both steps (the output fc's bias; its weights are zero), W_intra with one lateral weight 1.0 from
# neuron 0 to neuron 1, b_intra = (0.25, 0.1); decoder W_D = (1, 2), b_D = 0, α_V^LI = 1 (D_last: O = V_2).
#
# paper   t = 1: C = (0.3, 0)       H = (0.3, 0)            S = (0, 0)   I_2 = W·S_1 + b = (0.25, 0.1)
#         t = 2: C = (0.7, 0.1)     H = (0.925, 0.1)        S = (1, 0)   O = 0 + 1 = 1
# authors t = 1: C = (0.55, 0.1)    H = (0.55, 0.1)         S = (1, 0)   I_2 = (0.25, 1.1)
#         t = 2: C = (0.825, 1.15)  H = (0.825, 1.225)      S = (1, 1)   O = 1 + 3 = 4
EXPECTED = {
    "paper": {"spikes": [[0.0, 0.0], [1.0, 0.0]], "membranes": [[0.3, 0.0], [0.925, 0.1]], "readout": 1.0},
    "authors": {"spikes": [[1.0, 0.0], [1.0, 1.0]], "membranes": [[0.55, 0.1], [0.825, 1.225]], "readout": 4.0},
}
TIMINGS = tuple(EXPECTED)


def hand_policy(timing: str) -> Policy:
    config = actor_config("ilc-san", hidden=(1,), population_in=1, population_out=2, timesteps=2, intra_timing=timing)
    actor = build_actor(config, 1, 1, [1.0], seeds=(0,))
    with torch.no_grad():
        output = actor.layers[-1]
        output.weight.zero_()
        output.bias.copy_(torch.tensor([[0.3, 0.0]]))
        actor.intra.weight.zero_()
        actor.intra.weight[0, 0, 1, 0] = 1.0  # to neuron 1 from neuron 0
        actor.intra.bias.copy_(torch.tensor([[[0.25, 0.1]]]))
        actor.decoder.weight.copy_(torch.tensor([[[1.0, 2.0]]]))
        actor.decoder.bias.zero_()
    actor.eval()
    return Policy(actor, config, "Pendulum-v1", np.zeros(1), np.ones(1), 3.0, np.array([1.0]), np.array([0.0]), {})


@pytest.mark.parametrize("engine", ["fast", "reference"])
@pytest.mark.parametrize("timing", TIMINGS)
def test_both_engines_give_the_hand_computed_case(timing, engine):
    expected = EXPECTED[timing]
    with torch.no_grad():
        output = hand_policy(timing).actor.run(torch.zeros(1, 1, 1), engine, membranes=True)
    assert output.output_spikes[0, :, 0].tolist() == expected["spikes"]
    np.testing.assert_allclose(output.membranes[0, :, 0].numpy(), expected["membranes"], atol=1e-6)
    assert float(output.readout) == pytest.approx(expected["readout"], abs=1e-6)
    assert float(output.action) == pytest.approx(math.tanh(expected["readout"]), abs=1e-6)


@pytest.mark.parametrize("weights", ["float32", "int8"])
@pytest.mark.parametrize("timing", TIMINGS)
def test_the_numpy_runtime_gives_the_hand_computed_case(timing, weights):
    policy = hand_policy(timing)
    arrays, meta = bundle_arrays(policy), bundle_meta(policy)
    assert meta["intra_timing"] == timing
    if weights == "int8":
        arrays, meta = quantize_bundle(arrays, meta)
    runtime = DeployedActor.from_arrays(arrays, meta)
    trains = runtime.spike_trains(np.zeros(1))
    np.testing.assert_array_equal(trains[-1], np.array(EXPECTED[timing]["spikes"], bool))
    # int8 rounds W_D = (1, 2) to multiples of 2/127: the readout within that
    tolerance = 1e-6 if weights == "float32" else 0.05
    assert float(runtime.act(np.zeros(1))[0]) == pytest.approx(math.tanh(EXPECTED[timing]["readout"]), abs=tolerance)


@pytest.mark.parametrize("timing", TIMINGS)
def test_nir_gives_the_hand_computed_case(timing):
    graph = build_graph(hand_policy(timing), target="generic")
    assert ("layer2_lif" in graph.nodes) and (graph.nodes["layer2_fc"].bias.shape[0] == (3 if timing == "paper" else 2))
    with torch.no_grad():
        encoded = hand_policy(timing).actor.encoder(torch.zeros(1, 1, 1)).values[0, :, 0].numpy()  # (T, P_in)
    voltages = simulate_nir(graph, encoded.astype(np.float32))
    assert float(list(voltages.values())[0][-1, 0]) == pytest.approx(EXPECTED[timing]["readout"], abs=1e-5)


def test_timing_changes_a_random_actor_only_through_the_intra_bias():
    """The same weights under both timings: different actions with b_intra, identical ones under a mask without it."""
    state = torch.randn(1, 64, 5, generator=torch.Generator().manual_seed(3))

    def actions(intra: str, timing: str) -> torch.Tensor:
        actor = build_actor(actor_config("ilc-san", hidden=(32,), intra=intra, intra_timing=timing), 5, 2, [1.0, 1.0])
        with torch.no_grad():
            actor.intra.bias.mul_(4.0) if actor.intra.mask.bias else None
        return actor(state)

    assert not torch.allclose(actions("intra", "paper"), actions("intra", "authors"), atol=1e-3)
    assert torch.equal(actions("self+lateral", "paper"), actions("self+lateral", "authors"))


@pytest.mark.parametrize("timing", TIMINGS)
def test_energy_counts_equal_the_runtimes_accumulates(timing):
    """A bias is a constant current, not a synaptic operation: the SOP counts follow the spikes under either
    timing, and the energy model's equal the runtime's event by event."""
    from spiking_policies import observations, random_policy

    policy = random_policy(intra_timing=timing)
    batch = observations(policy, 8)
    runtime = DeployedActor.from_arrays(bundle_arrays(policy), bundle_meta(policy))
    for row in batch:
        runtime.act(row)
    report = energy_report(policy, measure_firing_rates(policy, batch))
    for layer in report.layers:
        assert runtime.total_sop_by_layer[layer.name] / len(batch) == pytest.approx(layer.sop, rel=1e-12, abs=1e-9)


def test_an_actor_saved_before_the_switch_existed_keeps_algorithm_1s_timing():
    """config.json, checkpoints, policies and bundles written without ``intra_timing`` ran Algorithm 1's timing, and
    load so whatever the presets' default is."""
    from ilcsan.config import SAVED_WITHOUT_INTRA_TIMING, ActorConfig

    saved = actor_config("ilc-san").to_dict()
    saved.pop("intra_timing")
    assert ActorConfig.from_dict(saved).intra_timing == SAVED_WITHOUT_INTRA_TIMING == "paper"
    policy = hand_policy("paper")
    arrays, meta = bundle_arrays(policy), bundle_meta(policy)
    meta.pop("intra_timing")
    trains = DeployedActor.from_arrays(arrays, meta).spike_trains(np.zeros(1))
    np.testing.assert_array_equal(trains[-1], np.array(EXPECTED["paper"]["spikes"], bool))
