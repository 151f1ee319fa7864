"""NIR export: CubaLIF parameters reproduce CLIF, and a written graph read back with ``nir.read`` and run by
``simulate_nir`` with the host parts gives the actor's actions."""

from __future__ import annotations

import json
from pathlib import Path

import nir
import numpy as np
import pytest
from spiking_policies import observations, random_policy

from ilcsan.deploy import DeployedActor
from ilcsan.deploy.bundle import bundle_arrays, bundle_meta
from ilcsan.deploy.nir import (
    build_graph,
    cubalif_parameters,
    export_nir,
    host_decode,
    host_encode,
    nir_action,
    read_host,
    simulate_nir,
)
from ilcsan.errors import UserError

ROUND_TRIP_TOLERANCE = 1e-5
DATA = Path(__file__).with_name("data")
WRITTEN_BEFORE = {"ilc-san": {"hidden": (16,), "intra": "lateral+bias"},
                  "popsan": {"hidden": (16,), "decoder": "fr", "intra": "none"}}
"""The actors of tests/data/*.nir, written by ``export_nir`` (commit 7040e47) before the ``sinabs`` target existed."""


def test_cubalif_parameters_of_the_paper():
    """dt = 1e-4 s: τ_syn = 0.2 ms, τ_mem = 0.4 ms, R = τ_mem/dt = 4 (snnTorch's importer asserts it), w_in = 2."""
    params = cubalif_parameters(0.5, 0.75, 0.5, 3)
    assert np.float32(1e-4) / params["tau_syn"][0] == 0.5 and np.float32(1e-4) / params["tau_mem"][0] == 0.25
    params.update(tau_syn=params["tau_syn"] / np.float32(1e-4), tau_mem=params["tau_mem"] / np.float32(1e-4))
    expected = {"tau_syn": 2.0, "w_in": 2.0, "tau_mem": 4.0, "r": 4.0, "v_leak": 0.0, "v_reset": 0.0,
                "v_threshold": 0.5}
    for name, value in expected.items():
        np.testing.assert_array_equal(params[name], np.full(3, value, np.float32))
    with pytest.raises(UserError, match="finite"):
        cubalif_parameters(0.5, 1.0, 0.5, 3)


def test_cubalif_euler_step_is_clif():
    """Input → identity Affine → CubaLIF: the interpreter's spikes equal Algorithm 1's CLIF on any currents."""
    rng = np.random.default_rng(0)
    currents = rng.normal(0.3, 0.6, (12, 50)).astype(np.float32)
    for alpha_c, alpha_v in ((0.5, 0.75), (0.25, 0.5), (0.0, 0.0)):
        graph = nir.NIRGraph(nodes={
            "input": nir.Input(input_type=np.array([50])),
            "affine": nir.Affine(weight=np.eye(50, dtype=np.float32), bias=np.zeros(50, np.float32)),
            "lif": nir.CubaLIF(**cubalif_parameters(alpha_c, alpha_v, 0.5, 50)),
            "output": nir.Output(output_type=np.array([50])),
        }, edges=[("input", "affine"), ("affine", "lif"), ("lif", "output")])
        simulated = simulate_nir(graph, currents, dt=1e-4)["output"]
        current, voltage, spikes = np.zeros(50, np.float32), np.zeros(50, np.float32), []
        for t in range(len(currents)):
            current = np.float32(alpha_c) * current + currents[t]
            voltage = np.float32(alpha_v) * voltage + current
            fired = voltage >= 0.5
            voltage = np.where(fired, 0, voltage).astype(np.float32)
            spikes.append(fired)
        np.testing.assert_array_equal(simulated, np.array(spikes, np.float32))
        assert 0.1 < simulated.mean() < 0.9


ROUND_TRIPS = [
    {}, {"intra": "self"}, {"intra": "lateral+bias"}, {"intra": "bias"}, {"intra": "none"},
    {"decoder": "max", "alpha_v_li": 0.5}, {"decoder": "mean", "alpha_v_li": 0.75}, {"hidden": (48,)},
    {"hidden": (40, 32, 24)}, {"timesteps": 8, "population_out": 7},
    {"encoder": "pop"}, {"encoder": "layer", "intra": "self+bias"}, {"decoder": "fr", "intra": "none"},
    {"intra_timing": "authors"}, {"intra_timing": "authors", "intra": "bias", "timesteps": 2},
]


def case_id(overrides: dict) -> str:
    return "-".join(f"{key}={value}" for key, value in overrides.items()) or "ilc-san"


@pytest.mark.parametrize("target", ["portable", "generic"])
@pytest.mark.parametrize("overrides", ROUND_TRIPS, ids=case_id)
def test_round_trip_matches_the_actor(tmp_path, overrides, target):
    policy = random_policy(**overrides)
    path = export_nir(policy, tmp_path / "actor.nir", target=target)
    graph = nir.read(path)
    batch = observations(policy, 10)
    actions = np.stack([nir_action(graph, observation) for observation in batch])
    error = float(np.abs(actions - policy.predict(batch)).max())
    assert error < ROUND_TRIP_TOLERANCE, error
    spikes = simulate_nir(graph, host_encode(read_host(graph), batch[0]))
    assert set(spikes) == {"output"}


def test_graph_layout(tmp_path):
    policy = random_policy(hidden=(32, 24))
    graph = nir.read(export_nir(policy, tmp_path / "actor.nir", target="generic"))
    types = {name: type(node).__name__ for name, node in graph.nodes.items()}
    assert types == {"input": "Input", "layer1_fc": "Affine", "layer1_lif": "CubaLIF", "layer2_fc": "Affine",
                     "layer2_lif": "CubaLIF", "layer3_fc": "Affine", "layer3_intra": "Linear", "layer3_lif": "CubaLIF",
                     "decoder": "Affine", "li": "I", "output": "Output"}
    edges = {tuple(edge) for edge in graph.edges}
    assert {("input", "layer1_fc"), ("layer3_lif", "layer3_intra"), ("layer3_intra", "layer3_lif"),
            ("layer3_lif", "decoder"), ("decoder", "li"), ("li", "output")} <= edges
    portable = nir.read(export_nir(policy, tmp_path / "portable.nir"))
    assert "li" not in portable.nodes and ("decoder", "output") in {tuple(e) for e in portable.edges}
    assert read_host(portable)["integrator"] == "host" and read_host(graph)["integrator"] == "graph"
    # the output population (30) plus the clock neuron that delivers b_intra from t = 2 on
    assert graph.nodes["layer3_lif"].v_threshold.shape == (31,)
    intra = graph.nodes["layer3_intra"].weight
    assert intra.shape == (31, 31) and not intra[:10, 10:30].any() and not intra[30].any()
    np.testing.assert_allclose(intra[:30, 30], policy.actor.intra.masked_bias()[0].detach().reshape(-1).numpy())
    assert not graph.nodes["decoder"].weight[:, 30].any()
    assert graph.metadata["format"] == "ilcsan-nir/2" and graph.metadata["dt"] == 1e-4
    assert graph.metadata["encoder_mu"].shape == (11, 10)
    host = read_host(graph)
    assert host["clock_neuron"] and host["T"] == graph.metadata["timesteps"] == 5 and host["statistic"] == "last"


def test_host_metadata_is_the_bundle_meta(tmp_path):
    policy = random_policy(hidden=(16,), decoder="mean", alpha_v_li=0.5)
    host = read_host(nir.read(export_nir(policy, tmp_path / "actor.nir")))
    for key, value in bundle_meta(policy).items():
        assert host[key] == value, key



def _damage_host(graph, change):
    host = json.loads(graph.metadata["host"])
    change(host)
    graph.metadata["host"] = json.dumps(host)


@pytest.mark.parametrize("damage, fragment", [
    (lambda g: g.metadata.update(host="{not json"), "not valid JSON"),
    (lambda g: g.metadata.update(host="[1, 2]"), "must be a JSON object"),
    (lambda g: _damage_host(g, lambda h: h.pop("statistic")), "lacks statistic"),
    (lambda g: _damage_host(g, lambda h: h.update(obs_std=[0.0] * len(h["obs_std"]))), "'obs_std' must be positive"),
    (lambda g: _damage_host(g, lambda h: h.update(obs_mean=["a"])), "'obs_mean' must be a list of numbers"),
    (lambda g: g.metadata.update(encoder_sigma=np.zeros_like(g.metadata["encoder_sigma"])), "has zeros"),
    (lambda g: g.metadata.update(encoder_mu=np.full_like(g.metadata["encoder_mu"], np.nan)), "NaN or inf"),
])
def test_damaged_host_metadata_is_one_user_error(damage, fragment):
    graph = build_graph(random_policy(hidden=(16,)))
    damage(graph)
    with pytest.raises(UserError, match=fragment) as error:
        nir_action(graph, np.zeros(11))
    assert "\n" not in str(error.value)

def test_host_encoder_is_the_numpy_runtimes(tmp_path):
    policy = random_policy(hidden=(16,))
    host = read_host(build_graph(policy))
    observation = observations(policy, 1)[0]
    runtime_trains = DeployedActor.from_arrays(bundle_arrays(policy), bundle_meta(policy)).spike_trains(observation)
    np.testing.assert_array_equal(host_encode(host, observation), runtime_trains[0].astype(np.float32))


def test_graphs_whose_host_names_the_timesteps_still_run(tmp_path):
    """Graphs written when ``host`` held ``timesteps`` (not the bundle's ``T``) read back with T from the graph."""
    policy = random_policy(hidden=(16,))
    graph = build_graph(policy)
    host = json.loads(graph.metadata["host"])
    host["timesteps"] = host.pop("T")
    graph.metadata["host"] = json.dumps(host)
    observation = observations(policy, 1)[0]
    assert np.abs(nir_action(graph, observation) - policy.predict(observation)).max() < ROUND_TRIP_TOLERANCE


def test_clock_neuron_delivers_the_intra_bias_from_step_two(tmp_path):
    """Without the clock, b_intra is missing; added at t = 1 too (a recurrent Affine) the actions differ."""
    policy = random_policy(intra="bias", gain=1.5, bias_shift=0.0)
    policy.actor.intra.bias.data.mul_(5.0)
    graph = build_graph(policy)
    host = read_host(graph)
    batch = observations(policy, 8)

    def actions(g):
        return np.stack([host_decode(host, simulate_nir(g, host_encode(host, obs))["output"]) for obs in batch])

    expected = policy.predict(batch)
    assert np.abs(actions(graph) - expected).max() < ROUND_TRIP_TOLERANCE
    no_clock = build_graph(policy)
    no_clock.nodes["layer3_intra"].weight[:, -1] = 0.0
    assert np.abs(actions(no_clock) - expected).max() > 1e-3
    at_step_one = build_graph(policy)
    bias = at_step_one.nodes["layer3_intra"].weight[:-1, -1].copy()
    at_step_one.nodes["layer3_fc"].bias[:-1] += bias  # b_intra at every step, t = 1 included
    at_step_one.nodes["layer3_intra"].weight[:, -1] = 0.0
    assert np.abs(actions(at_step_one) - expected).max() > 1e-3


def test_leaky_decoder_is_nir_li(tmp_path):
    graph = build_graph(random_policy(decoder="mean", alpha_v_li=0.75), target="generic")
    li = graph.nodes["li"]
    assert isinstance(li, nir.LI)
    np.testing.assert_array_equal(li.tau, np.full(3, np.float32(1e-4) * 4, np.float32))
    np.testing.assert_array_equal(li.r, np.full(3, 4.0, np.float32))


def test_export_refusals(tmp_path):
    for preset, overrides, message in (("dan", {}, "DAN"), ("mdc-san", {}, "dynamic"),
                                       ("ilc-san", {"alpha_v": 1.0}, "finite")):
        with pytest.raises(UserError, match=message):
            export_nir(random_policy(preset, **overrides), tmp_path / "x.nir")
    assert not (tmp_path / "x.nir").exists()
    foreign = nir.NIRGraph(nodes={"input": nir.Input(input_type=np.array([2])),
                                  "output": nir.Output(output_type=np.array([2]))}, edges=[("input", "output")])
    with pytest.raises(UserError, match="host metadata"):
        read_host(foreign)
    np.testing.assert_array_equal(simulate_nir(foreign, np.ones((3, 2)))["output"], np.ones((3, 2)))


def test_export_command_writes_nir_for_a_trained_run(trained_run, tmp_path):
    from ilcsan import load
    from ilcsan.deploy.export import export

    path = export(trained_run, "nir", tmp_path / "pendulum.nir")
    graph = nir.read(path)
    policy = load(trained_run)
    observation = np.array([0.3, -0.9, 0.5])
    assert np.abs(nir_action(graph, observation) - policy.predict(observation)).max() < ROUND_TRIP_TOLERANCE


def _same(written, built) -> bool:
    if isinstance(written, np.ndarray) or isinstance(built, np.ndarray):
        written, built = np.asarray(written), np.asarray(built)
        return written.shape == built.shape and np.array_equal(written, built)
    return written == built


@pytest.mark.parametrize("path", sorted(DATA.glob("*.nir")), ids=lambda path: path.stem)
def test_targets_write_what_they_wrote_before(tmp_path, path):
    """A target never changes what another writes: each graph in tests/data, written before the ``sinabs`` target
    existed, equals what ``export_nir`` writes now for the same actor and target (nodes, their arrays, edges in
    order, metadata; of the host JSON, the keys the bundle's meta does not own)."""
    name, target = path.stem.split(".")
    written, policy = nir.read(path), random_policy(**WRITTEN_BEFORE[name])
    built = nir.read(export_nir(policy, tmp_path / path.name, target=target))
    assert list(built.edges) == list(written.edges)
    assert sorted(built.nodes) == sorted(written.nodes)
    for node_name, node in written.nodes.items():
        fields, now = node.to_dict(), built.nodes[node_name].to_dict()
        assert sorted(now) == sorted(fields), node_name
        for field, value in fields.items():
            assert _same(value, now[field]), (node_name, field)
    assert sorted(built.metadata) == sorted(written.metadata)
    for key, value in written.metadata.items():
        if key != "host":
            assert _same(value, built.metadata[key]), key
    # the host JSON: the bundle's meta (shared with --format npz) may change on its own; the graph's own keys may not
    meta = bundle_meta(policy)
    host, host_before = json.loads(built.metadata["host"]), json.loads(written.metadata["host"])
    for key in set(host) | set(host_before):
        assert host.get(key) == (meta[key] if key in meta else host_before.get(key)), key


def test_sinabs_target_is_the_portable_graph_in_sinabs_steps(tmp_path):
    """``--target sinabs``: each CubaLIF as nir.LI (α_C) then nir.LIF (α_V) with exp(−1/τ) = α, r = 1, no v_reset in
    the file (nir 1.0.4 reads none), the intra Linear as a zero-bias Affine on the same recurrent edge, dt = 1, and
    every other node and the host metadata as in ``portable`` (Sinabs runs it: tests/test_nir_consumers.py)."""
    import h5py

    policy = random_policy(hidden=(32, 24), alpha_c=0.25, alpha_v=0.6)
    path = export_nir(policy, tmp_path / "actor.nir", target="sinabs")
    with h5py.File(path) as file:
        assert not [name for name, group in file["node"]["nodes"].items() if "v_reset" in group]
    graph, portable = nir.read(path), build_graph(policy, "portable")
    types = {name: type(node).__name__ for name, node in graph.nodes.items()}
    assert types == {"input": "Input", "layer1_fc": "Affine", "layer1_syn": "LI", "layer1_lif": "LIF",
                     "layer2_fc": "Affine", "layer2_syn": "LI", "layer2_lif": "LIF", "layer3_fc": "Affine",
                     "layer3_syn": "LI", "layer3_lif": "LIF", "layer3_intra": "Affine", "decoder": "Affine",
                     "output": "Output"}
    assert list(graph.edges) == [
        ("input", "layer1_fc"), ("layer1_fc", "layer1_syn"), ("layer1_syn", "layer1_lif"), ("layer1_lif", "layer2_fc"),
        ("layer2_fc", "layer2_syn"), ("layer2_syn", "layer2_lif"), ("layer2_lif", "layer3_fc"),
        ("layer3_fc", "layer3_syn"), ("layer3_syn", "layer3_lif"), ("layer3_lif", "layer3_intra"),
        ("layer3_intra", "layer3_syn"), ("layer3_lif", "decoder"), ("decoder", "output")]
    for index in (1, 2, 3):
        syn, lif = graph.nodes[f"layer{index}_syn"], graph.nodes[f"layer{index}_lif"]
        np.testing.assert_allclose(np.exp(-1.0 / syn.tau), 0.25, rtol=1e-6)
        np.testing.assert_allclose(np.exp(-1.0 / lif.tau), 0.6, rtol=1e-6)
        for node in (syn, lif):
            np.testing.assert_array_equal(node.r, 1.0)
            np.testing.assert_array_equal(node.v_leak, 0.0)
        np.testing.assert_array_equal(lif.v_threshold, portable.nodes[f"layer{index}_lif"].v_threshold)
        np.testing.assert_array_equal(lif.v_reset, 0.0)  # nir 1.0.8's default for the missing field
    intra = graph.nodes["layer3_intra"]
    np.testing.assert_array_equal(intra.weight, portable.nodes["layer3_intra"].weight)
    assert intra.bias.shape == (intra.weight.shape[0],) and not intra.bias.any()
    for name in ("layer1_fc", "layer2_fc", "layer3_fc", "decoder"):
        np.testing.assert_array_equal(graph.nodes[name].weight, portable.nodes[name].weight)
        np.testing.assert_array_equal(graph.nodes[name].bias, portable.nodes[name].bias)
    assert graph.metadata["dt"] == 1.0
    host, portable_host = json.loads(graph.metadata["host"]), json.loads(portable.metadata["host"])
    assert (host.pop("target"), portable_host.pop("target")) == ("sinabs", "portable")
    assert host.pop("timing") != portable_host.pop("timing")
    assert host == portable_host and read_host(graph)["integrator"] == "host"
    for key in ("encoder_mu", "encoder_sigma", "timesteps", "format"):
        np.testing.assert_array_equal(graph.metadata[key], portable.metadata[key])
    with pytest.raises(UserError, match="finite"):
        build_graph(random_policy(alpha_v=1.0), "sinabs")
