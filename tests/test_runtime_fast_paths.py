"""The runtime's fast paths compute what their plain forms compute: the folded intra-layer accumulate, the
decoder's table, the encoder's reset by subtraction, the normaliser without np.clip, the CLIF loop."""

from __future__ import annotations

import numpy as np
import pytest
from spiking_policies import observations, random_policy

from ilcsan.config import INTRA_MASKS as INTRA_VARIANTS
from ilcsan.deploy import DeployedActor
from ilcsan.deploy.bundle import bundle_arrays, bundle_meta
from ilcsan.deploy.quantize import quantize_bundle
from ilcsan.runtime.host import deterministic_spike_train, li_voltages, normalize
from ilcsan.runtime.neurons import neuron_step
from ilcsan.runtime.pipeline import Workspace
from ilcsan.runtime.synapses import Synapses, accumulate_steps, steps_accumulator


def runtime(policy, int8: bool = False) -> DeployedActor:
    arrays, meta = bundle_arrays(policy), bundle_meta(policy)
    return DeployedActor.from_arrays(*(quantize_bundle(arrays, meta) if int8 else (arrays, meta)))


def plain_run(workspace: Workspace) -> None:
    """The tick loop without the CLIF fast path: each layer's own accumulate, then :func:`neuron_step`."""
    workspace.reset()
    workspace._run_any_neuron()


@pytest.mark.parametrize("timing", ["paper", "authors"])
@pytest.mark.parametrize("variant", [v for v in INTRA_VARIANTS if v != "none"])
def test_folded_intra_gives_the_unfolded_spikes(variant, timing):
    policy = random_policy(intra=variant, hidden=(40, 24), intra_timing=timing)
    actor = runtime(policy)
    folded = actor.workspace
    unfolded = Workspace(actor.timesteps, actor.layers, actor.neuron, actor.intra, fold_intra=False,
                         intra_bias_at_first_step=timing == "authors")
    assert folded.add_intra is None and unfolded.add_intra is not None
    for observation in observations(policy, 20):
        actor.spike_trains(observation)
        unfolded.encoded[...] = folded.encoded
        plain_run(unfolded)
        for ours, plain in zip(folded.trains, unfolded.trains, strict=True):
            np.testing.assert_array_equal(ours, plain)


@pytest.mark.parametrize("int8", [False, True], ids=["float", "int8"])
def test_clif_loop_equals_the_generic_neuron_step(int8):
    policy = random_policy(intra="lateral+bias", hidden=(32, 32))
    actor = runtime(policy, int8)
    workspace = actor.workspace
    assert workspace._clif is not None and workspace._inline is not int8
    assert (workspace.add_intra is not None) is int8  # int8: the intra accumulate stays separate (its own scale)
    for observation in observations(policy, 10):
        trains = [train.copy() for train in actor.spike_trains(observation)]
        plain_run(workspace)
        for ours, plain in zip(trains, workspace.trains, strict=True):
            np.testing.assert_array_equal(ours, plain)


@pytest.mark.parametrize("scale", [None, 0.01])
def test_decoder_table_equals_bincount(scale):
    rng = np.random.default_rng(0)
    populations, size, steps = 4, 10, 5
    dtype = np.float32 if scale is None else np.int8
    weights = (rng.normal(size=(populations * size, 1)) * (1 if scale is None else 50)).astype(dtype)
    synapses = Synapses("Group FC", weights, np.repeat(np.arange(populations), size)[:, None], scale,
                        rng.normal(size=populations).astype(np.float32), populations, 1)
    add = steps_accumulator(synapses)
    for _ in range(50):
        spikes = rng.random((steps, populations * size)) < rng.random()
        currents, sop = add(spikes)
        expected, expected_sop = accumulate_steps(synapses, spikes)
        np.testing.assert_array_equal(currents, expected)
        assert currents.dtype == np.float32 and sop == expected_sop


def test_encoder_and_normaliser_equal_their_plain_forms():
    rng = np.random.default_rng(1)
    for _ in range(50):
        stimulation = rng.random(60).astype(np.float32) ** rng.uniform(0.2, 3)
        voltage, plain = np.zeros_like(stimulation), []
        for _ in range(7):  # Eq. (4) as written: v ← v + A; S = [v > V_th]; v ← v − V_th S
            voltage = voltage + stimulation
            plain.append(voltage > np.float32(0.999))
            voltage = np.where(plain[-1], voltage - np.float32(0.999), voltage)
        np.testing.assert_array_equal(deterministic_spike_train(stimulation, 7, 0.999), np.stack(plain))
        observation = rng.normal(size=11) * 10
        mean, std = rng.normal(size=11), rng.uniform(0.1, 2, 11)
        np.testing.assert_array_equal(normalize(observation, mean, std, 5.0),
                                      np.clip((observation - mean) / std, -5.0, 5.0).astype(np.float32))
    inputs = rng.normal(size=(5, 3)).astype(np.float32)
    np.testing.assert_array_equal(li_voltages(inputs, 1.0), np.cumsum(inputs, axis=0, dtype=np.float32))


def test_dynamic_neuron_actor_runs_the_generic_step(monkeypatch):
    policy = random_policy(neuron="dynamic", intra="self+bias")
    actor = runtime(policy)
    assert actor.workspace._clif is None and actor.workspace.add_intra is None  # folded, generic neuron step
    calls = []

    def counting(*args):
        calls.append(1)
        return neuron_step(*args)

    monkeypatch.setattr("ilcsan.runtime.pipeline.neuron_step", counting)
    batch = observations(policy, 5)
    assert np.abs(actor.act(batch) - policy.predict(batch)).max() <= 1e-4
    assert len(calls) == 5 * len(actor.workspace.ticks)
