"""Exported NIR graphs run in the real consumers (snnTorch 1.0.0, Norse 1.1.0, SpikingJelly 2.0.0, through NIRTorch
2.6): driven by the host encoder's spikes for T steps, their actions equal ``policy.predict`` on 50 observations.
Needs the ``nir`` extra (``pip install -e .[nir]``, installed by scripts/setup); a missing consumer fails, never
skips. Sinabs 3.1.3 pins nir ≤ 1.0.4, so it runs the target-``sinabs`` graphs in its own environment
(``scripts/setup-sinabs``, which the test script runs with --if-possible; this test skips, saying why, without it)."""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import subprocess
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
SINABS_PYTHON_VARIABLE = "ILCSAN_SINABS_PYTHON"
SINABS_ENVIRONMENT = DOCS.parent / ".venv-sinabs"


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
    """The consumer snippets of docs/nir-consumers.md (``**Name version**`` then a python block), dedented."""
    text = (DOCS / "nir-consumers.md").read_text()
    blocks = re.findall(r"^  \*\*(\S+) [\d.]+\*\*.*?```python\n(.*?)^  ```", text, re.S | re.M)
    return {name.lower(): textwrap.dedent(code) for name, code in blocks}


@pytest.mark.parametrize("consumer", ["norse", "snntorch", "spikingjelly"])
def test_documented_snippets_run_as_written(tmp_path, monkeypatch, consumer):
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


def sinabs_python() -> Path:
    """Sinabs's Python: ``$ILCSAN_SINABS_PYTHON``, else the checkout's .venv-sinabs once scripts/setup-sinabs has
    finished; skips the test, saying why, when neither exists."""
    configured = os.environ.get(SINABS_PYTHON_VARIABLE)
    python = Path(configured) if configured else SINABS_ENVIRONMENT / "bin" / "python"
    if not python.exists() or not (configured or (SINABS_ENVIRONMENT / ".ilcsan-installed").exists()):
        pytest.skip(f"Sinabs's environment {python} is missing or incomplete: run `bash scripts/setup-sinabs` (or set "
                    f"{SINABS_PYTHON_VARIABLE} to a Python with sinabs 3.1.3)")
    return python


def test_sinabs_runs_the_sinabs_target_as_predict(tmp_path):
    """Every case exported with ``--target sinabs``, read with nir 1.0.4 and run by Sinabs 3.1.3 (``sinabs_module``,
    50 observations as one batch), and the documented Sinabs snippet as written: ``predict``'s actions to 1e-5."""
    python = sinabs_python()
    expected = {}
    for name, overrides in CASES.items():
        policy = random_policy(**overrides)
        batch = observations(policy, 50)
        export_nir(policy, tmp_path / f"{name}.nir", target="sinabs")
        np.save(tmp_path / f"{name}.obs.npy", batch)
        expected[name] = policy.predict(batch)
    code = snippets()["sinabs"]
    assert len(code.strip().splitlines()) <= 10
    (tmp_path / "snippet.py").write_text(code)
    policy = random_policy(intra="lateral+bias")
    (tmp_path / "snippet").mkdir()
    export_nir(policy, tmp_path / "snippet" / "actor.nir", target="sinabs")
    np.save(tmp_path / "snippet" / "observations.npy", observations(policy, 3))
    source = str(Path(__file__).resolve().parents[1] / "src")
    environment = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [source, os.environ.get("PYTHONPATH")])))
    done = subprocess.run([str(python), str(Path(__file__).with_name("sinabs_check.py")), str(tmp_path)],
                          capture_output=True, text=True, timeout=600, env=environment)
    assert done.returncode == 0, done.stderr[-3000:]
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["versions"] == {"sinabs": "3.1.3", "nir": "1.0.4"}
    for name, actions in expected.items():
        error = float(np.abs(np.array(results["actions"][name]) - actions).max())
        assert error <= TOLERANCE, (name, error)
        assert np.abs(actions).max() > 0.1
    error = np.abs(np.array(results["snippet"]) - policy.predict(observations(policy, 3))).max()
    assert error <= TOLERANCE, error
