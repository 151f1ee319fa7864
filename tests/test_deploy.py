"""The additions-only runtime: numpy only, equal to the PyTorch actor for every fully spiking switch, and
its synaptic-operation count equal to the energy model's."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from spiking_policies import FULLY_SPIKING, HAND_SOP, case_id, deployed, hand_made_policy, observations, random_policy

import ilcsan.deploy
import ilcsan.runtime
from ilcsan.analysis.energy import energy_report, measure_firing_rates
from ilcsan.config import INTRA_MASKS as INTRA_VARIANTS
from ilcsan.config import actor_config
from ilcsan.deploy import DeployedActor
from ilcsan.deploy.bundle import actor_config_of, bundle_arrays, bundle_meta, export_npz
from ilcsan.errors import UserError
from ilcsan.runtime.bundle_format import mask_of_variant

RUNTIME_FOLDER = Path(ilcsan.runtime.__file__).parent
DEPLOY_FOLDER = Path(ilcsan.deploy.__file__).parent
TOLERANCE = 1e-4

# --------------------------------------------------------------------------------- equality
@pytest.mark.parametrize("case", FULLY_SPIKING, ids=case_id)
def test_runtime_equals_pytorch_and_counts_the_energy_models_sop(case):
    preset, overrides = case
    policy = random_policy(preset, **overrides)
    batch = observations(policy, 12)
    runtime = deployed(policy)
    actions = np.stack([runtime.act(row) for row in batch])
    expected = policy.predict(batch)
    assert np.abs(actions - expected).max() < TOLERANCE
    rates = measure_firing_rates(policy, batch)  # spiking is non-trivial in every layer
    assert all(0.02 < rate < 0.98 for rate in rates.rates.values()), rates.rates
    report = energy_report(policy, rates)
    assert runtime.inferences == len(batch)
    for layer in report.layers:
        assert runtime.total_sop_by_layer[layer.name] / len(batch) == pytest.approx(layer.sop, rel=1e-12, abs=1e-9)
    assert runtime.total_sop / len(batch) == pytest.approx(report.total_sop, rel=1e-12)


def test_one_timestep_has_no_intra_step():
    policy = random_policy(timesteps=1, bias_shift=0.6)
    batch = observations(policy, 8)
    runtime = deployed(policy)
    assert np.abs(runtime.act(batch) - policy.predict(batch)).max() < TOLERANCE
    assert runtime.total_sop_by_layer["Intra FC"] == 0 < runtime.total_sop_by_layer["FC2"]


def test_ant_sized_actor_and_batches():
    policy = random_policy(state_dim=111, action_dim=8)
    batch = observations(policy, 6)
    runtime = deployed(policy)
    assert np.abs(runtime.act(batch) - policy.predict(batch)).max() < TOLERANCE
    single = runtime.act(batch[0])
    assert single.shape == (8,) and single.dtype == np.float32
    assert runtime.last_sop == sum(runtime.last_sop_by_layer.values()) > 0


def test_spike_trains_equal_the_actors():
    policy = random_policy(hidden=(48, 32))
    observation = observations(policy, 1)[0]
    output = policy.run(observation)
    trains = deployed(policy).spike_trains(observation)
    expected = [inputs[0, :, 0].numpy() for inputs in output.layer_inputs] + [output.output_spikes[0, :, 0].numpy()]
    assert len(trains) == len(expected) == 4
    for ours, theirs in zip(trains, expected, strict=True):
        np.testing.assert_array_equal(ours, theirs.astype(bool))


def test_hand_made_actor_sop_per_layer():
    policy = hand_made_policy()
    meta = dict(bundle_meta(policy), intra="intra")  # its intra weights are all 0: name the mask
    runtime = DeployedActor.from_arrays(bundle_arrays(policy), meta)
    runtime.act(np.array([0.3, -0.2, 1.0]))
    assert runtime.last_sop_by_layer == {"FC1": 30, "FC2": 18, "Intra FC": 14, "Group FC": 9} == HAND_SOP
    assert runtime.last_sop == 71
    runtime.act(np.zeros(3))
    assert runtime.total_sop == 142 and runtime.inferences == 2
    old_meta = {key: value for key, value in bundle_meta(policy).items() if key not in ("intra", "intra_mask")}
    inferred = DeployedActor.from_arrays(bundle_arrays(policy), old_meta)  # a bundle that does not name its mask:
    inferred.act(np.zeros(3))  # all-zero weights are inferred to be no synapses at all
    assert inferred.last_sop_by_layer["Intra FC"] == 0 and inferred.last_sop == 57


def test_bundle_file_round_trip(tmp_path):
    policy = random_policy()
    path = export_npz(policy, tmp_path / "actor.npz")
    runtime = DeployedActor.load(path)
    batch = observations(policy, 5)
    assert np.abs(runtime.act(batch) - policy.predict(batch)).max() < TOLERANCE
    with np.load(path, allow_pickle=False) as bundle:
        assert all(bundle[name].dtype == np.float32 for name in bundle.files if name != "meta")


def test_a_bundle_whose_encoder_width_is_zero_is_refused_in_one_line():
    policy = random_policy()
    arrays = bundle_arrays(policy)
    arrays["encoder.sigma"] = arrays["encoder.sigma"].copy()
    arrays["encoder.sigma"][1, 2] = 0.0
    with pytest.raises(UserError, match="'encoder.sigma' has zeros") as error:
        DeployedActor.from_arrays(arrays, bundle_meta(policy))
    assert "\n" not in str(error.value)
    arrays["encoder.sigma"][1, 2] = -0.4  # a negative width is the same Gaussian (σ enters squared)
    flipped = DeployedActor.from_arrays(arrays, bundle_meta(policy))
    assert np.all(np.isfinite(flipped.act(np.zeros(flipped.state_dim))))


# ------------------------------------------------------------------------------- no PyTorch
def _fresh_python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)


def test_standalone_folder_runs_a_bundle_without_torch(tmp_path):
    """The runtime folder copied on its own (under another name, no ilcsan around it) loads and runs a bundle."""
    policy = random_policy()
    path = export_npz(policy, tmp_path / "actor.npz")
    observation = observations(policy, 1)[0]
    robot = tmp_path / "robot"
    shutil.copytree(RUNTIME_FOLDER, robot / "deployed_actor", ignore=shutil.ignore_patterns("__pycache__"))
    code = f"""
import json, sys
sys.path.insert(0, {str(robot)!r})
from deployed_actor import DeployedActor, UserError
actor = DeployedActor.load({str(path)!r})
action = actor.act({observation.tolist()!r})
print(json.dumps({{"torch": "torch" in sys.modules, "ilcsan": any(name.startswith("ilcsan") for name in sys.modules),
                  "local_error": UserError.__module__, "action": action.tolist(), "sop": actor.last_sop}}))
"""
    result = _fresh_python(code)
    assert result.returncode == 0, result.stderr
    data = json.loads(result.stdout)
    assert data["torch"] is False and data["ilcsan"] is False
    assert data["local_error"] == "deployed_actor.errors"
    assert np.abs(np.array(data["action"]) - policy.predict(observation)).max() < TOLERANCE
    assert data["sop"] > 0


def test_package_import_without_torch():
    """``import ilcsan`` and ``import ilcsan.deploy`` must not import torch (the package imports it lazily)."""
    package_alone = _fresh_python("import sys, ilcsan; print('torch' in sys.modules)")
    assert package_alone.returncode == 0, package_alone.stderr
    assert package_alone.stdout.strip() == "False"
    result = _fresh_python("import sys, ilcsan.deploy; print('torch' in sys.modules)")
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "False"


def test_old_runtime_path_warns_and_gives_the_runtimes_objects(monkeypatch):
    """``ilcsan.deploy.runtime``, the runtime's former path, warns and hands on :mod:`ilcsan.runtime`'s own objects,
    its modules included."""
    import importlib

    monkeypatch.delitem(sys.modules, "ilcsan.deploy.runtime", raising=False)
    with pytest.warns(DeprecationWarning, match="ilcsan.runtime"):
        old = importlib.import_module("ilcsan.deploy.runtime")
    assert all(getattr(old, name) is getattr(ilcsan.runtime, name) for name in ilcsan.runtime.__all__)
    from ilcsan.deploy.runtime.host import normalize

    assert normalize is ilcsan.runtime.host.normalize
    assert old.pipeline is importlib.import_module("ilcsan.runtime.pipeline")


def test_runtime_modules_import_numpy_only():
    modules = sorted(RUNTIME_FOLDER.glob("*.py"))
    assert {path.name for path in modules} >= {"__init__.py", "actor.py", "host.py", "bundle_format.py"}
    for path in modules:
        imports = [line.split()[1] for line in path.read_text().splitlines()
                   if line.strip().startswith(("import ", "from "))]
        assert "torch" not in " ".join(imports), path.name
        external = {name for name in imports if not name.startswith(".")}
        assert external <= {"__future__", "json", "math", "numbers", "collections.abc", "dataclasses", "pathlib",
                            "typing", "numpy"}, path.name
        assert all(name in (".errors", "..errors") or name.count(".") == 1 for name in imports
                   if name.startswith(".")), path.name  # only siblings, and the package's UserError


def test_package_modules_stay_under_400_lines():
    for path in [*RUNTIME_FOLDER.glob("*.py"), *DEPLOY_FOLDER.glob("*.py")]:
        assert len(path.read_text().splitlines()) <= 400, path.name


# ----------------------------------------------------------------------------------- refusals
@pytest.mark.parametrize(("preset", "overrides", "message"), [
    ("ilc-san", {"encoder": "pop-prob"}, "pop-prob"),
    ("ilc-san", {"encoder": "pop"}, "not fully spiking"),
    ("akl", {}, "not fully spiking"),
    ("popsan", {}, "not fully spiking"),
    ("mdc-san", {}, "not fully spiking"),
    ("dan", {}, "DAN"),
])
def test_refuses_actors_that_are_not_fully_spiking(preset, overrides, message):
    policy = random_policy(preset, **overrides)
    with pytest.raises(UserError, match=message):
        DeployedActor.from_arrays(bundle_arrays(policy), bundle_meta(policy))


def _saved(tmp_path, arrays, meta) -> Path:
    path = tmp_path / "bundle.npz"
    np.savez(path, meta=np.array(json.dumps(meta)), **arrays)
    return path


def test_load_errors(tmp_path):
    policy = random_policy(hidden=(16, 16))
    arrays, meta = bundle_arrays(policy), bundle_meta(policy)
    with pytest.raises(UserError, match="does not exist"):
        DeployedActor.load(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip file")
    with pytest.raises(UserError, match="not a readable"):
        DeployedActor.load(tmp_path / "junk.npz")
    np.savez(tmp_path / "nometa.npz", **arrays)
    with pytest.raises(UserError, match="no 'meta'"):
        DeployedActor.load(tmp_path / "nometa.npz")
    broken = {name: value for name, value in arrays.items() if name != "layers.1.bias"}
    with pytest.raises(UserError, match="layers.1.bias"):
        DeployedActor.load(_saved(tmp_path, broken, meta))
    misshaped = dict(arrays, **{"decoder.weight": np.zeros((3, 9), np.float32)})
    with pytest.raises(UserError, match=r"decoder.weight.*\(3, 9\)"):
        DeployedActor.load(_saved(tmp_path, misshaped, meta))
    with pytest.raises(UserError, match="NaN"):
        DeployedActor.from_arrays(dict(arrays, **{"layers.0.bias": np.full(16, np.nan, np.float32)}), meta)
    np.savez(tmp_path / "badjson.npz", meta=np.array("{not json"), **arrays)
    with pytest.raises(UserError, match="JSON"):
        DeployedActor.load(tmp_path / "badjson.npz")


@pytest.mark.parametrize(("change", "message"), [
    ({"T": "five"}, "'T'"), ({"T": 0}, "'T'"), ({"obs_std": [-1.0] * 11}, "obs_std"),
    ({"action_offset": [0.0]}, "action_offset"), ({"v_reset": 0.5}, "reset"), ({"neuron": "izhikevich"}, "neuron"),
    ({"intra": "sideways"}, "intra"), ({"statistic": "median"}, "statistic|fully spiking"),
    ({"intra_mask": {"self_weights": True}}, "intra_mask"), ({"intra_mask": [True, True, True]}, "intra_mask"),
    ({"intra": "self"}, "disagree"),
])
def test_bad_meta(change, message):
    policy = random_policy(hidden=(16, 16))
    meta = dict(bundle_meta(policy), **change)
    with pytest.raises(UserError, match=message):
        DeployedActor.from_arrays(bundle_arrays(policy), meta)
    meta = {key: value for key, value in bundle_meta(policy).items() if key != "obs_clip"}
    with pytest.raises(UserError, match="obs_clip"):
        DeployedActor.from_arrays(bundle_arrays(policy), meta)


def test_bad_observations():
    runtime = deployed(random_policy(hidden=(16, 16)))
    for bad in (np.zeros(10), np.zeros((2, 3, 11)), [np.nan] * 11, "eleven"):
        with pytest.raises(UserError):
            runtime.act(bad)


def test_intra_mask_from_meta_equals_mask_from_weights():
    policy = random_policy(intra="lateral+bias")
    arrays, meta = bundle_arrays(policy), bundle_meta(policy)
    inferred = DeployedActor.from_arrays(arrays, meta)
    named = DeployedActor.from_arrays(arrays, dict(meta, intra="lateral+bias"))
    assert inferred.intra.fan_out == named.intra.fan_out == 9
    np.testing.assert_array_equal(inferred.intra.targets, named.intra.targets)


# ------------------------------------------------------------------------------- the bundle's meta
def old_bundle_meta(policy) -> dict:
    """The meta as bundles written before the meta was built from ActorConfig.to_dict (names only, no flags)."""
    c = policy.actor_config
    return {
        "T": c.timesteps, "alpha_c": c.alpha_c, "alpha_v": c.alpha_v, "v_th": c.v_th, "v_reset": 0.0,
        "alpha_v_li": c.alpha_v_li, "v_reset_li": 0.0, "statistic": c.decoder, "encoder": c.encoder,
        "enc_v_th": c.enc_v_th, "obs_mean": policy.obs_mean.tolist(), "obs_std": policy.obs_std.tolist(),
        "obs_clip": policy.obs_clip, "action_scale": policy.action_scale.tolist(),
        "action_offset": policy.action_offset.tolist(), "output": "tanh", "neuron": c.neuron,
        "network": c.network, "preset": c.preset, "task": policy.task, "population_out": c.population_out,
        "intra": c.intra, "population_in": c.population_in,
    }


@pytest.mark.parametrize("variant", INTRA_VARIANTS)
def test_old_bundles_load_and_act_the_same(tmp_path, variant):
    policy = random_policy(intra=variant, hidden=(24, 16))
    arrays = bundle_arrays(policy)
    old = DeployedActor.load(_saved(tmp_path, arrays, old_bundle_meta(policy)))
    new = DeployedActor.load(export_npz(policy, tmp_path / "new.npz"))
    batch = observations(policy, 6)
    np.testing.assert_array_equal(old.act(batch), new.act(batch))
    assert old.total_sop_by_layer == new.total_sop_by_layer
    assert set(old_bundle_meta(policy)) <= set(bundle_meta(policy))  # every key an old runtime reads is written


@pytest.mark.parametrize("variant", INTRA_VARIANTS)
def test_variant_names_parse_to_the_configs_masks(variant):
    assert mask_of_variant(variant) == tuple(INTRA_VARIANTS[variant])
    assert bundle_meta(random_policy(intra=variant, hidden=(8,)))["intra_mask"] == INTRA_VARIANTS[variant]._asdict()


def test_bundle_meta_is_the_config_under_the_bundles_keys():
    config = actor_config("ilc-san", hidden=(16, 12), intra="self+bias", decoder="max", alpha_v_li=0.75, timesteps=7)
    policy = random_policy(**{key: getattr(config, key) for key in ("hidden", "intra", "decoder", "alpha_v_li",
                                                                      "timesteps")})
    meta = json.loads(json.dumps(bundle_meta(policy)))
    assert actor_config_of(meta) == policy.actor_config == config
    assert meta["T"] == 7 and meta["statistic"] == "max" and "timesteps" not in meta and "decoder" not in meta
