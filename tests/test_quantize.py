"""int8 bundles: the file holds int8 weights with per-layer scales, the runtime accumulates them exactly,
and the actions stay close to the float actor's."""

from __future__ import annotations

import numpy as np
import pytest
from spiking_policies import observations, random_policy

from ilcsan.deploy import SCALE_SUFFIX, DeployedActor
from ilcsan.deploy.bundle import bundle_arrays, bundle_meta, export_npz
from ilcsan.deploy.quantize import dequantize_weight, is_synaptic_weight, quantize_bundle, quantize_weight
from ilcsan.errors import UserError


def test_quantize_weight_is_symmetric_per_tensor():
    weight = np.array([[0.5, -1.27], [0.0, 0.004]], np.float32)
    quantized, scale = quantize_weight(weight)
    assert quantized.dtype == np.int8 and scale == np.float32(0.01)
    np.testing.assert_array_equal(quantized, [[50, -127], [0, 0]])
    assert np.abs(dequantize_weight(quantized, scale) - weight).max() <= scale / 2 + 1e-7
    zeros, unit = quantize_weight(np.zeros((2, 2)))
    assert unit == 1.0 and not zeros.any()
    with pytest.raises(UserError):
        quantize_weight(np.array([np.inf]))


def test_bundle_names_and_meta():
    policy = random_policy(intra="lateral+bias")
    arrays, meta = bundle_arrays(policy), bundle_meta(policy)
    quantized, new_meta = quantize_bundle(arrays, meta)
    weights = [name for name in arrays if is_synaptic_weight(name)]
    assert weights == ["layers.0.weight", "layers.1.weight", "layers.2.weight", "intra.weight", "decoder.weight"]
    for name in weights:
        assert quantized[name].dtype == np.int8
        assert quantized[name + SCALE_SUFFIX].dtype == np.float32 and quantized[name + SCALE_SUFFIX].shape == ()
    for name in ("layers.0.bias", "intra.bias", "decoder.bias", "encoder.mu", "encoder.sigma"):
        np.testing.assert_array_equal(quantized[name], arrays[name])
    eye = np.eye(10, dtype=bool)
    assert not quantized["intra.weight"][:, eye].any()  # the masked self weights stay exactly zero
    assert new_meta["weights"] == "int8" and new_meta["quantization"]["weights"] == weights
    assert "weights" not in meta  # inputs untouched
    with pytest.raises(UserError, match="already"):
        quantize_bundle(quantized, new_meta)


def test_saved_file_holds_int8_and_runs(tmp_path):
    policy = random_policy()
    path = export_npz(policy, tmp_path / "actor.int8.npz", weights="int8")
    with np.load(path, allow_pickle=False) as bundle:
        dtypes = {name: bundle[name].dtype for name in bundle.files}
    assert dtypes["layers.0.weight"] == dtypes["intra.weight"] == dtypes["decoder.weight"] == np.int8
    assert dtypes["layers.0.weight.scale"] == np.float32 and dtypes["layers.0.bias"] == np.float32
    runtime = DeployedActor.load(path)
    assert runtime.layers[0].weights.dtype == np.int8 and runtime.layers[0].scale > 0
    assert runtime.act(observations(policy, 1)[0]).shape == (3,)


@pytest.mark.parametrize("sizes", [(11, 3), (111, 8)])
def test_int8_actions_close_to_float(sizes):
    state_dim, action_dim = sizes
    policy = random_policy(state_dim=state_dim, action_dim=action_dim)
    arrays, meta = bundle_arrays(policy), bundle_meta(policy)
    quantized, quantized_meta = quantize_bundle(arrays, meta)
    batch = observations(policy, 100)
    float_actions = DeployedActor.from_arrays(arrays, meta).act(batch)
    int8_runtime = DeployedActor.from_arrays(quantized, quantized_meta)
    int8_actions = int8_runtime.act(batch)
    error = np.abs(int8_actions - float_actions) / (2 * policy.action_scale)  # fraction of the action range
    assert error.mean() < 0.04 and np.median(error) < 0.01
    # the integer accumulation is exact: same actions as float weights equal to scale · q
    dequantized = {name: dequantize_weight(value, quantized[name + SCALE_SUFFIX]) if value.dtype == np.int8
                   else value for name, value in quantized.items() if not name.endswith(SCALE_SUFFIX)}
    assert np.abs(DeployedActor.from_arrays(dequantized, meta).act(batch) - int8_actions).max() < 1e-5
    assert int8_runtime.total_sop > 0


def test_int8_bundle_errors():
    policy = random_policy(hidden=(16, 16))
    quantized, meta = quantize_bundle(bundle_arrays(policy), bundle_meta(policy))
    without_scale = {name: value for name, value in quantized.items() if name != "layers.1.weight" + SCALE_SUFFIX}
    with pytest.raises(UserError, match="no scale"):
        DeployedActor.from_arrays(without_scale, meta)
    negative = dict(quantized, **{"decoder.weight" + SCALE_SUFFIX: np.float32(-1.0)})
    with pytest.raises(UserError, match="positive"):
        DeployedActor.from_arrays(negative, meta)
