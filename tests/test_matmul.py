"""The matmul paths (:mod:`ilcsan.compute.matmul`): every float32 path computes the same products, gradients and
TD3 updates; bf16 really rounds; the choice is the measured fastest, is recorded in config.json, and reaches the
networks as an explicit object (no process-wide setting)."""

from __future__ import annotations

import json
from itertools import pairwise

import pytest
import torch

from ilcsan.compute.matmul import (
    FLOAT32_PATHS,
    MatmulPath,
    bf16_operands,
    ensemble_matmul,
    fastest_float32_path,
    gaining_products,
    layer_products,
    measure_paths,
    onednn_available,
    product_times,
)
from ilcsan.compute.programs import DirectProgram, value_and_grads
from ilcsan.config import RunConfig, TrainingConfig, actor_config
from ilcsan.errors import UserError
from ilcsan.rl.matmul_choice import run_products
from ilcsan.rl.training import Trainer
from ilcsan.snn.ensemble import EnsembleLinear, EnsembleMLP, seed_generators

PATHS = [path for path in FLOAT32_PATHS if path != "onednn" or onednn_available()]


@pytest.fixture
def restore_path():
    """Put back torch's float32 matmul precision."""
    precision = torch.get_float32_matmul_precision()
    yield
    torch.set_float32_matmul_precision(precision)


@pytest.mark.parametrize("path", [*PATHS, "bf16"])
def test_every_path_computes_a_times_w_transposed_per_member(path):
    generator = torch.Generator().manual_seed(3)
    a, w = torch.randn(3, 37, 20, generator=generator), torch.randn(3, 11, 20, generator=generator)
    exact = torch.einsum("kri,koi->kro", a.double(), w.double())
    # the backward products come with transposed views: those must work too
    for left, right in ((a, w), (a.transpose(1, 2).contiguous().transpose(1, 2), w.transpose(1, 2).contiguous()
                                 .transpose(1, 2))):
        result = ensemble_matmul(left, right, path)
        assert result.dtype == torch.float32 and result.shape == (3, 37, 11)
        if path == "bf16":  # 8-bit mantissas: about 1 % error, but never exact
            assert torch.allclose(result.double(), exact, rtol=0.05, atol=0.3)
            assert not torch.allclose(result.double(), exact, rtol=1e-5, atol=1e-5)
        else:
            torch.testing.assert_close(result.double(), exact, rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("path", PATHS)
def test_layer_gradients_agree_on_every_float32_path(path):
    x = torch.randn(2, 4, 6, 7, requires_grad=True)

    def grads(kind: str):
        layer = EnsembleLinear(2, 7, 5, matmul_path=MatmulPath(kind))
        layer.reset_parameters(seed_generators([0, 1], 0))
        x.grad = None
        (layer(x) ** 2).sum().backward()
        return x.grad.clone(), layer.weight.grad.clone(), layer.bias.grad.clone()

    reference = grads("aten")
    for ours, theirs in zip(grads(path), reference, strict=True):
        torch.testing.assert_close(ours, theirs, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("compiled", [False, True])
def test_first_layer_weight_gradient_on_onednn_equals_mkls(compiled):
    """A first layer's weight gradient (its input needs none) on oneDNN equals MKL's, eagerly and compiled as the
    update program compiles it (:func:`value_and_grads` in a :class:`DirectProgram`). Compiled through
    ``torch.func.grad_and_value`` instead, torch 2.13 returns it as zeros — why the program does not use it."""
    if not onednn_available():
        pytest.skip("this torch has no oneDNN")
    from torch.func import functional_call, grad_and_value

    x = torch.randn(2, 16, 5, generator=torch.Generator().manual_seed(0))

    def network(kind: str):
        mlp = EnsembleMLP(2, [5, 16, 1], MatmulPath(kind))
        mlp.reset_parameters(seed_generators([1, 2], 0))
        return mlp

    names = [name for name, _ in network("aten").named_parameters()]
    params = [p.detach() for p in network("aten").parameters()]
    mlp = network("aten")

    def loss(tensors):
        return (functional_call(mlp, dict(zip(names, tensors, strict=True)), (x,)) ** 2).sum()

    reference, _ = value_and_grads(loss, params)
    mlp = network("onednn")
    with torch.no_grad():
        def gradients(tensors):
            return value_and_grads(loss, tensors)

        grads, _ = (DirectProgram(gradients) if compiled else gradients)(params)
    for ours, theirs in zip(grads, reference, strict=True):
        torch.testing.assert_close(ours, theirs, rtol=1e-5, atol=1e-6)
    assert torch.count_nonzero(grads[0]) > 0
    if compiled:
        functorch = torch.compile(grad_and_value(loss), fullgraph=True)(params)[0]
        torch._dynamo.reset()
        assert torch.count_nonzero(functorch[0]) == 0


def test_the_fastest_measured_float32_path_is_chosen():
    assert fastest_float32_path({"aten": 90.0, "onednn": 180.0}) == "onednn"
    assert fastest_float32_path({"aten": 90.0, "onednn": 80.0, "bf16": 400.0}) == "aten"  # bf16 only when asked
    assert fastest_float32_path({"aten": 90.0, "onednn": 90.0}) == "aten"
    speeds = measure_paths(layer_products(1, 64, 32, 32), seconds=0.01)
    assert set(speeds) == set(PATHS) and all(value > 0 for value in speeds.values())


def test_paths_are_judged_by_the_time_a_step_spends_not_by_flops(monkeypatch):
    """A product a step runs every time outweighs a large one it runs once per evaluation: with times where oneDNN
    is 5x slower on acting's small product and 2x faster on the diagnostics' large one, unweighted totals pick oneDNN,
    the per-step counts aten; the GFLOP/s are Σ count·flops / Σ count·time."""
    import ilcsan.compute.matmul as matmul

    small, large = layer_products(1, 5, 30, 8)[0], layer_products(1, 5000, 30, 8)[0]
    fake = {small: (1e-6, 5e-6), large: (1e-2, 5e-3)}
    monkeypatch.setattr(matmul, "onednn_available", lambda: True)
    monkeypatch.setattr(matmul, "product_times", lambda products, fused_casts, seconds, paths: {
        product: fake[product] for product in products})
    once = measure_paths([small, large])
    assert fastest_float32_path(once) == "onednn"
    per_step = measure_paths({small: 1.0, large: 1e-4})
    assert fastest_float32_path(per_step) == "aten"
    flops = 2 * 5 * 30 * 8 * (1.0 + 1e-4 * 1000)
    assert per_step["aten"] == pytest.approx(flops / (1e-6 + 1e-4 * 1e-2) / 1e9)
    assert per_step["onednn"] == pytest.approx(flops / (5e-6 + 1e-4 * 5e-3) / 1e9)


def test_run_products_counts_how_often_a_step_computes_each_product():
    """Hand-counted for ILC-SAN on a 3-observation, 1-action task (pop-det encoder: 3·10 = 30 inputs, T = 5, one
    hidden layer of 8, 10 output neurons), 2 seeds, batch 16, policy delay 2, evaluations of 4 episodes of at most
    200 steps every 500 steps, twin critics of 12."""
    config = RunConfig(task="Pendulum-v1", seeds=(0, 1), eval_every=500, eval_episodes=4,
                       actor=actor_config("ilc-san", hidden=(8,)),
                       training=TrainingConfig(batch_size=16, critic_hidden=(12,), policy_delay=2))
    counts = run_products(config, 3, 1, episode_steps=200)
    forward, grad_input, grad_weight = layer_products(2, 5 * 16, 30, 8)
    assert counts[layer_products(2, 5, 30, 8)[0]] == 1.0  # acting, every step
    assert counts[forward] == 1.0 + 0.5 and counts[grad_input] == counts[grad_weight] == 0.5  # target, actor update
    assert counts[layer_products(2, 5 * 4, 30, 8)[0]] == pytest.approx(200 / 500)  # evaluation
    assert counts[layer_products(2, 5 * 1000, 8, 10)[0]] == pytest.approx(1 / 500)  # diagnostics
    twin_forward, twin_input, _ = layer_products(4, 16, 4, 12)
    assert counts[twin_forward] == 2.0 and counts[twin_input] == 1.0  # critic loss and target critics
    assert counts[layer_products(2, 16, 12, 1)[1]] == 0.5  # the actor loss through the first critics
    # per actor layer 3 update products and 3 forward ones (acting, evaluation, diagnostics); per critic layer 3 of
    # the twin critics and 3 of the first critics: nothing else
    assert len(counts) == 2 * (3 + 3) + 2 * (3 + 3)


def test_a_run_records_its_matmul_choice_in_config_json(tmp_path, restore_path):
    lines = []
    config = RunConfig(task="Pendulum-v1", steps=10, eval_every=10, eval_episodes=1, threads=1,
                       actor=actor_config("ilc-san", hidden=(8,)),
                       training=TrainingConfig(start_steps=10, update_after=10))
    Trainer(config, tmp_path / "run", progress=False, log=lines.append).close()
    recorded = json.loads((tmp_path / "run" / "config.json").read_text())["matmul_path"]
    assert recorded["path"] in PATHS and not recorded["compiled"]
    assert set(recorded["gflops"]) == set(PATHS)
    assert recorded["path"] == fastest_float32_path(recorded["gflops"])
    assert [line for line in lines if line.startswith(f"matmul: {recorded['path']} (float32 GFLOP/s")]
    assert RunConfig.from_dict(json.loads((tmp_path / "run" / "config.json").read_text())).actor == config.actor
    bf16 = RunConfig(**{**config.__dict__, "matmul": "bf16"})
    Trainer(bf16, tmp_path / "bf16", progress=False, log=lines.append).close()
    recorded = json.loads((tmp_path / "bf16" / "config.json").read_text())["matmul_path"]
    assert recorded["path"] == "bf16" and recorded["products"] == len(set(run_products(bf16, 3, 1)))
    assert {(tuple(a), tuple(w)) for a, w in recorded["bf16_products"]} <= set(run_products(bf16, 3, 1))
    assert lines[-1].startswith(f"matmul: bf16 on {len(recorded['bf16_products'])} of this run's "
                                f"{recorded['products']} product shapes")


def test_a_resumed_run_keeps_the_path_it_started_on_unless_another_matmul_is_asked_for(tmp_path, monkeypatch,
                                                                                       restore_path):
    """The float32 paths round differently: a run measured aten faster at its start and resumed where oneDNN
    measures faster still continues on aten (its curve then equals an uninterrupted run's); asked for bf16 on
    resume, it measures anew."""
    if not onednn_available():
        pytest.skip("this torch has no oneDNN")
    import ilcsan.rl.run_setup as run_setup
    import ilcsan.rl.training as training
    from ilcsan.rl.matmul_choice import choose_matmul_path

    def measuring(fastest: str):
        def choose(config, state_dim, action_dim, episode_steps=None):
            if config.matmul == "bf16":
                return choose_matmul_path(config, state_dim, action_dim, episode_steps)
            return MatmulPath(fastest), {"path": fastest, "compiled": False, "gflops": {"aten": 1.0, "onednn": 1.0}}
        return choose

    config = RunConfig(task="Pendulum-v1", steps=20, eval_every=10, eval_episodes=1, threads=1,
                       actor=actor_config("ilc-san", hidden=(8,)),
                       training=TrainingConfig(start_steps=10, update_after=5))
    monkeypatch.setattr(run_setup, "choose_matmul_path", measuring("aten"))
    training.train(RunConfig(**{**config.__dict__, "steps": 10}), tmp_path / "run", progress=False, log=print)
    monkeypatch.setattr(run_setup, "choose_matmul_path", measuring("onednn"))
    lines: list[str] = []
    trainer = Trainer(config, tmp_path / "run", resume=True, progress=False, log=lines.append)
    try:
        assert trainer.matmul_choice["path"] == "aten"
        assert any(line.startswith("matmul: aten (kept from the run's start") for line in lines)
    finally:
        trainer.close()
    bf16 = RunConfig(**{**config.__dict__, "matmul": "bf16"})
    trainer = Trainer(bf16, tmp_path / "run", resume=True, progress=False, log=lines.append)
    try:
        assert trainer.matmul_choice["path"] == "bf16" and "kept" not in trainer.matmul_choice
    finally:
        trainer.close()


def test_a_named_float32_path_is_taken_as_named_and_wins_over_the_one_a_resumed_run_began_on(tmp_path, monkeypatch,
                                                                                             restore_path):
    """--matmul aten / onednn: no measurement (it would raise here), the path recorded as named; a run resumed with
    the path it began on keeps it, with the other one it computes on the one named now."""
    import ilcsan.rl.matmul_choice as matmul_choice
    import ilcsan.rl.training as training

    def no_measuring(*_):
        raise AssertionError("a named path is not measured")

    monkeypatch.setattr(matmul_choice, "measure_paths", no_measuring)
    config = RunConfig(task="Pendulum-v1", steps=10, eval_every=10, eval_episodes=1, threads=1, matmul="aten",
                       actor=actor_config("ilc-san", hidden=(8,)),
                       training=TrainingConfig(start_steps=10, update_after=5))
    lines: list[str] = []
    training.train(config, tmp_path / "run", progress=False, log=lines.append)
    recorded = json.loads((tmp_path / "run" / "config.json").read_text())["matmul_path"]
    assert recorded == {"path": "aten", "compiled": False, "gflops": {}, "named": True}
    assert "matmul: aten (as --matmul names it, not measured)" in lines
    for asked, kept in (("aten", True), *((("onednn", False),) if onednn_available() else ())):
        resumed = Trainer(RunConfig(**{**config.__dict__, "steps": 20, "matmul": asked}), tmp_path / "run",
                          resume=True, progress=False, log=lines.append)
        try:
            assert resumed.matmul_choice["path"] == asked and bool(resumed.matmul_choice.get("kept")) is kept
        finally:
            resumed.close()
    monkeypatch.setattr(matmul_choice, "onednn_available", lambda: False)
    with pytest.raises(UserError, match="--matmul onednn: this build of torch has no oneDNN"):
        Trainer(RunConfig(**{**config.__dict__, "matmul": "onednn"}), tmp_path / "none", progress=False,
                log=lines.append)


def test_a_bf16_run_rounds_only_the_products_it_measured_faster_in_bfloat16(restore_path):
    assert gaining_products({((1, 5, 4), (1, 3, 4)): (1.0, 0.9), ((1, 5, 3), (1, 4, 3)): (1.0, 0.91),
                             ((1, 3, 5), (1, 4, 5)): (1.0, 2.0)}) == {((1, 5, 4), (1, 3, 4))}
    generator = torch.Generator().manual_seed(4)
    big, small = ((1, 40, 30), (1, 20, 30)), ((1, 40, 6), (1, 20, 6))
    path = MatmulPath("bf16", {big})
    assert path.product_path(*big) == "bf16" and path.product_path(*small) == "aten"
    for shapes, rounded in ((big, True), (small, False)):
        a, w = torch.randn(shapes[0], generator=generator), torch.randn(shapes[1], generator=generator)
        exact = torch.bmm(a.double(), w.double().transpose(1, 2))
        result = ensemble_matmul(a, w, path.product_path(a.shape, w.shape))
        assert torch.allclose(result.double(), exact, rtol=1e-5, atol=1e-5) is not rounded
    assert MatmulPath("bf16").product_path(*small) == "bf16"  # no list: every product


def test_a_layer_runs_its_products_on_the_path_it_was_built_with():
    """No process-wide setting: two layers built with different paths in one process keep their own."""
    generator = torch.Generator().manual_seed(5)
    x = torch.randn(1, 40, 30, generator=generator)
    exact, rounded = (EnsembleLinear(1, 30, 20, matmul_path=MatmulPath(kind)) for kind in ("aten", "bf16"))
    for layer in (exact, rounded):
        layer.reset_parameters(seed_generators([0], 0))
        reference = torch.baddbmm(exact.bias.unsqueeze(1).double(), x.double(), exact.weight.double().transpose(1, 2))
        assert torch.allclose(exact(x).double(), reference, atol=1e-5)
        assert not torch.allclose(rounded(x).double(), reference, atol=1e-5)
        assert torch.allclose(exact(x).double(), reference, atol=1e-5)  # the bf16 layer changed nothing else


def test_bf16_operands_come_contiguous_in_one_cast():
    a, w = torch.randn(2, 7, 5), torch.randn(2, 3, 5).transpose(1, 2).contiguous().transpose(1, 2)
    a16, wt16 = bf16_operands(a, w)
    assert a16.dtype == wt16.dtype == torch.bfloat16 and a16.is_contiguous() and wt16.is_contiguous()
    assert torch.equal(wt16, w.transpose(1, 2).to(torch.bfloat16)) and wt16.shape == (2, 5, 3)


def test_timing_both_paths_gives_every_distinct_product_two_positive_times():
    products = layer_products(1, 16, 8, 4) * 2
    times = product_times(products, fused_casts=True, seconds=0.0005)
    assert set(times) == set(products) and all(f32 > 0 and b16 > 0 for f32, b16 in times.values())


@pytest.mark.parametrize(("preset", "options", "target", "algorithm"), [
    ("ilc-san", {}, "polyak", "td3"), ("dan", {}, "polyak", "td3"), ("ilc-san", {}, "proxy", "td3"),
    ("ilc-san", {"encoder": "pop"}, "polyak", "td3"), ("ilc-san", {}, "polyak", "ddpg"),
    ("ilc-san", {}, "polyak", "sac"), ("dan", {}, "polyak", "sac")])
def test_run_products_lists_every_product_a_run_computes(tmp_path, preset, options, target, algorithm, monkeypatch):
    """The bf16 choice is made per product shape from ``run_products``: a shape missing from it would silently
    stay float32. Records every product of a short run (updates, acting, evaluation, the proxy's fit) of each
    algorithm."""
    import ilcsan.snn.ensemble as ensemble

    seen = set()
    forward, backward = ensemble._EnsembleAffine.forward, ensemble._EnsembleAffine.backward

    def recording_forward(flat, weight, bias, paths):
        seen.add((tuple(flat.shape), tuple(weight.shape)))
        return forward(flat, weight, bias, paths)

    def recording_backward(ctx, grad_output):
        flat, weight = ctx.saved_tensors
        k, rows, d_in = flat.shape
        d_out = weight.shape[1]
        seen.update({((k, rows, d_out), (k, d_in, d_out)), ((k, d_out, rows), (k, d_in, rows))})
        return backward(ctx, grad_output)

    monkeypatch.setattr(ensemble._EnsembleAffine, "forward", staticmethod(recording_forward))
    monkeypatch.setattr(ensemble._EnsembleAffine, "backward", staticmethod(recording_backward))
    config = RunConfig(task="Pendulum-v1", seeds=(0, 1), steps=160, eval_every=160, eval_episodes=2, threads=1,
                       actor=actor_config(preset, hidden=(8,), **options), compile="off", algorithm=algorithm,
                       training=TrainingConfig(start_steps=150, update_after=150, batch_size=16, critic_hidden=(12,),
                                     target_actor=target))
    trainer = Trainer(config, tmp_path / "run", progress=False, log=lambda *_: None)
    try:
        trainer.train()
    finally:
        trainer.close()
    assert seen and seen <= set(run_products(config, 3, 1)), sorted(seen - set(run_products(config, 3, 1)))


def test_a_proxy_runs_products_are_what_its_declaration_says(monkeypatch):
    """run_products names no method: a proxy run's products are a plain run's changed by Proxy Target's declared
    hook (the proxy's fit and forward, the actor's forward over its regression targets, no target actor's pass)."""
    from ilcsan.methods.proxy_target import PROXY_HIDDEN, ProxyTargetDeclaration

    def config(target_actor: str) -> RunConfig:
        return RunConfig(task="Pendulum-v1", seeds=(0, 1), eval_every=500, eval_episodes=4,
                         actor=actor_config("ilc-san", hidden=(8,)),
                         training=TrainingConfig(batch_size=16, critic_hidden=(12,), target_actor=target_actor,
                                       proxy_iterations=3))

    plain, proxy = run_products(config("polyak"), 3, 1, 200), run_products(config("proxy"), 3, 1, 200)
    forward = layer_products(2, 5 * 16, 30, 8)[0]
    assert plain[forward] == 1.5 and proxy[forward] == 0.5  # the target actor's pass is gone, the actor update's stays
    assert proxy[layer_products(2, 5 * 16 * 3, 30, 8)[0]] == 1.0  # the actor's forward over the K·B targets
    assert {product for product in proxy if product not in plain} == {
        product for d_in, d_out in pairwise([3, *PROXY_HIDDEN, 1]) for product in layer_products(2, 16, d_in, d_out)
    } | {layer_products(2, 5 * 16 * 3, 30, 8)[0], layer_products(2, 5 * 16 * 3, 8, 10)[0]}
    for d_in, d_out in ((3, PROXY_HIDDEN[0]), (PROXY_HIDDEN[-1], 1)):  # (a square layer's two products share a shape)
        fit = layer_products(2, 16, d_in, d_out)
        assert [proxy[product] for product in fit] == [4.0, 3.0, 3.0]  # K regression steps, and π' once more
    monkeypatch.setattr(ProxyTargetDeclaration, "products", classmethod(lambda cls, *args: None))
    assert run_products(config("proxy"), 3, 1, 200) == plain  # without its hook, nothing of the proxy is counted
