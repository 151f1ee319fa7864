"""Exported NIR graphs run in the real consumers (snnTorch 1.0.0, Norse 1.1.0, SpikingJelly 2.0.0, through NIRTorch
2.6): driven by the host encoder's spikes for T steps, their actions equal ``policy.predict`` on 50 observations.
Needs the ``nir`` extra (``pip install -e .[nir]``, installed by scripts/setup); a missing consumer fails, never
skips."""

from __future__ import annotations

import contextlib
import io
import re
import textwrap
from pathlib import Path

import nir
import numpy as np
import pytest
from spiking_policies import observations, random_policy

from ilcsan.deploy.nir import export_nir, host_decode, host_encode, read_host
from ilcsan.deploy.nir.consumers import norse_module, run_module, snntorch_module, spikingjelly_module

TOLERANCE = 1e-5
CASES = {"ilc-san": {}, "popsan": {"decoder": "fr", "intra": "none"}, "self": {"intra": "self"},
         "lateral+bias": {"intra": "lateral+bias"}, "authors-timing": {"intra_timing": "authors"},
         "max-leaky-deep": {"decoder": "max", "alpha_v_li": 0.75, "hidden": (40, 32, 24), "timesteps": 8}}
"""ILC-SAN (I_intra, last decoder), PopSAN (``fr``), the intra masks ``self`` and ``lateral+bias`` (the clock neuron),
b_intra from t = 1 (the authors' timing), and D_max with a leaky LI, three hidden layers and T = 8."""
DOCS = Path(__file__).resolve().parents[1] / "docs"


def consumer_actions(graph, load, batch: np.ndarray) -> np.ndarray:
    host = read_host(graph)
    spikes = np.stack([host_encode(host, observation) for observation in batch], axis=1)  # (T, B, D)
    with contextlib.redirect_stdout(io.StringIO()):  # snnTorch prints its progress
        outputs = run_module(load(graph), spikes)
    return np.stack([host_decode(host, outputs[:, index]) for index in range(len(batch))])


@pytest.mark.parametrize("load", [snntorch_module, norse_module, spikingjelly_module],
                         ids=["snntorch", "norse", "spikingjelly"])
@pytest.mark.parametrize("case", list(CASES))
def test_consumer_reproduces_predict(tmp_path, case, load):
    policy = random_policy(**CASES[case])
    graph = nir.read(export_nir(policy, tmp_path / "actor.nir"))
    assert graph.metadata["dt"] == pytest.approx(1e-4)
    batch = observations(policy, 50)
    expected = policy.predict(batch)
    error = float(np.abs(consumer_actions(graph, load, batch) - expected).max())
    assert error <= TOLERANCE, error
    assert np.abs(expected).max() > 0.1  # a real action, not a silent network


def test_snntorch_import_from_nir_runs_feed_forward_graphs(tmp_path):
    from snntorch.import_nir import import_from_nir

    policy = random_policy(**CASES["popsan"])
    graph = nir.read(export_nir(policy, tmp_path / "actor.nir"))
    batch = observations(policy, 50)
    error = np.abs(consumer_actions(graph, import_from_nir, batch) - policy.predict(batch)).max()
    assert error <= TOLERANCE, error


def minimal_recurrent_graph(size: int = 2) -> nir.NIRGraph:
    """input → identity Affine → CubaLIF ⇄ Linear(0) → output, independent of ilcsan's export."""
    lif = {"tau_syn": np.full(size, 2e-4), "tau_mem": np.full(size, 4e-4), "r": np.full(size, 4.0),
           "v_leak": np.zeros(size), "v_threshold": np.ones(size), "v_reset": np.zeros(size),
           "w_in": np.full(size, 2.0)}
    return nir.NIRGraph(nodes={
        "input": nir.Input(input_type=np.array([size])),
        "fc": nir.Affine(weight=np.eye(size, dtype=np.float32), bias=np.zeros(size, np.float32)),
        "lif": nir.CubaLIF(**lif), "rec": nir.Linear(weight=np.zeros((size, size), np.float32)),
        "output": nir.Output(output_type=np.array([size]))},
        edges=[("input", "fc"), ("fc", "lif"), ("lif", "rec"), ("rec", "lif"), ("lif", "output")])


def test_snntorch_recurrent_rewrite_is_wrong_and_the_workaround_is_right():
    """The upstream bug (docs/nir-snntorch-recurrent-bug.md): with W_rec = 0 snnTorch's importer silences the
    neuron; the NIR semantics (our interpreter) and the workaround spike at t = 2..5."""
    from snntorch.import_nir import import_from_nir

    from ilcsan.deploy.nir import simulate_nir

    drive = np.full((5, 1, 2), 0.6, np.float32)
    expected = simulate_nir(minimal_recurrent_graph(), drive[:, 0], dt=1e-4)["output"]
    np.testing.assert_array_equal(expected[:, 0], [0, 1, 1, 1, 1])
    with contextlib.redirect_stdout(io.StringIO()):
        upstream = run_module(import_from_nir(minimal_recurrent_graph()), drive)[:, 0]
        fixed = run_module(snntorch_module(minimal_recurrent_graph()), drive)[:, 0]
    assert not upstream.any()  # remove this test's upstream half once snnTorch fixes the rewrite
    np.testing.assert_array_equal(fixed, expected)


def snippets() -> dict[str, str]:
    """The README's consumer snippets (Deployment section, ``**Name version**`` then a python block), dedented."""
    text = (DOCS.parent / "README.md").read_text()
    blocks = re.findall(r"^  \*\*(\S+) [\d.]+\*\*.*?```python\n(.*?)^  ```", text, re.S | re.M)
    return {name.lower(): textwrap.dedent(code) for name, code in blocks}


@pytest.mark.parametrize("consumer", ["norse", "snntorch", "spikingjelly"])
def test_readme_snippets_run_as_written(tmp_path, monkeypatch, consumer):
    code = snippets()[consumer]
    assert len(code.strip().splitlines()) <= 10
    policy = random_policy(intra="lateral+bias")
    monkeypatch.chdir(tmp_path)
    export_nir(policy, tmp_path / "actor.nir")
    for observation in observations(policy, 3):
        scope = {"observation": observation}
        with contextlib.redirect_stdout(io.StringIO()):
            exec(code, scope)  # noqa: S102 - the documented snippet, as a user runs it
        assert np.abs(scope["action"] - policy.predict(observation)).max() <= TOLERANCE
