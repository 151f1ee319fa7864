"""The matmul path of a run, chosen by measuring the run's own products at its start, and kept when it resumes."""

from __future__ import annotations

from collections.abc import Mapping
from itertools import pairwise
from typing import Any

import torch

from .. import methods
from ..compute.matmul import (
    FLOAT32_PATHS,
    MATMUL_PATHS,
    MatmulPath,
    Product,
    fastest_float32_path,
    gaining_products,
    layer_products,
    measure_paths,
    onednn_available,
    product_times,
)
from ..config import SPIKING_ENCODERS, RunConfig
from ..errors import UserError
from ..snn.diagnostics import DIAGNOSTIC_STATES
from .algorithms import algorithm_class


def run_products(config: RunConfig, state_dim: int, action_dim: int,
                 episode_steps: int | None = None) -> dict[Product, float]:
    """The (a, w) shapes of the products of this run (:data:`~ilcsan.compute.matmul.Product`), each with how many
    times the run computes it per environment step once updates run (one update a step; ``update_every`` steps, then
    as many updates), for the run's algorithm (:mod:`ilcsan.rl.algorithms`: its critics per seed C, the critics its
    actor loss evaluates, its policy delay d, its actor's readouts per action) and for its methods (what each declares
    it changes, :meth:`~ilcsan.methods.Declared.products`). For each actor layer: acting's forward product over T rows
    (every step); an update's products over T·B rows: the forward of the actor giving the next actions (TD3's and
    DDPG's target actor, SAC's own actor; every update, unless a method gives them from a network of its own) and the
    forward and both backward products of the actor update (every d-th); evaluation's forward over T·E rows (at most
    ``episode_steps`` steps every ``eval_every``; 1000, Gymnasium's MuJoCo limit, when not given); the diagnostics'
    over T·1000 rows (once per evaluation, the deployed actor's: its first readout only); the methods' further
    forward passes of the actor. T is 1 for DAN and for a first layer whose input is not a spike train. For every
    critic layer: the C·K critics' three products (the critic loss) and their forward again (the target critics),
    every update; the three products of the critics the actor loss evaluates (every d-th update). Then the products
    of the methods' own networks."""
    algorithm = algorithm_class(config.algorithm)
    seeds, training, actor = len(config.seeds), config.training, config.actor
    batch = training.batch_size
    changes = methods.MethodProducts()
    for method in methods.of_run(config):
        method.products(training, state_dim, action_dim, changes)
    delayed = 1.0 / algorithm.policy_delay(training)
    evaluations = 1.0 / config.eval_every
    timesteps = actor.timesteps if actor.network == "spiking" else 1
    counts: dict[Product, float] = {}

    def add(products: list[Product], times: float) -> None:
        for product in products:
            counts[product] = counts.get(product, 0.0) + times

    forward_rows = [(1, 1.0), (config.eval_episodes, (episode_steps or 1000) * evaluations), *changes.actor_forwards]
    trained = pairwise(actor.layer_sizes(state_dim, algorithm.readouts * action_dim))
    deployed = pairwise(actor.layer_sizes(state_dim, action_dim))  # the diagnostics' actor: the first readout
    for index, ((d_in, d_out), (_, deployed_out)) in enumerate(zip(trained, deployed, strict=True)):
        steps = timesteps if index > 0 or actor.encoder in SPIKING_ENCODERS else 1
        update = layer_products(seeds, steps * batch, d_in, d_out)
        add(update, delayed)
        add(update[:1], changes.next_actions_by_actor)
        for rows, times in forward_rows:
            add(layer_products(seeds, steps * rows, d_in, d_out)[:1], times)
        add(layer_products(seeds, steps * DIAGNOSTIC_STATES, d_in, deployed_out)[:1], evaluations)
    for d_in, d_out in pairwise([state_dim + action_dim, *training.critic_hidden, 1]):
        every = layer_products(algorithm.critics * seeds, batch, d_in, d_out)
        add(every, 1.0)
        add(every[:1], 1.0)
        add(layer_products(algorithm.actor_loss_critics * seeds, batch, d_in, d_out), delayed)
    for widths, rows, times, forward_times in changes.networks:
        for d_in, d_out in pairwise(widths):
            products = layer_products(seeds, rows, d_in, d_out)
            add(products, times)
            add(products[:1], forward_times)
    return counts


def choose_matmul_path(config: RunConfig, state_dim: int, action_dim: int,
                       episode_steps: int | None = None) -> tuple[MatmulPath, dict]:
    """The matmul path of the run's networks (:mod:`ilcsan.compute.matmul`) and what was chosen, for config.json and
    the start-up line. float32: the faster float32 path on the run's own products, measured now. aten, onednn: that
    path, not measured (the same in every run). bf16: bfloat16 for the products it computes faster, measured now as
    the run will compute them (casts fused when compiled), float32 (``aten``) for the others."""
    if torch.device(config.device).type != "cpu":
        return MatmulPath("aten"), {"path": "aten", "gflops": {}}
    compiled = config.compiles()
    if config.matmul in FLOAT32_PATHS:
        if config.matmul == "onednn" and not onednn_available():
            raise UserError("--matmul onednn: this build of torch has no oneDNN linear kernel; use --matmul aten, "
                            "or float32 to measure")
        return MatmulPath(config.matmul), {"path": config.matmul, "compiled": compiled, "gflops": {}, "named": True}
    products = run_products(config, state_dim, action_dim, episode_steps)
    if config.matmul == "bf16":
        times = product_times(products, fused_casts=compiled)
        gaining = gaining_products(times)
        float32_seconds, bf16_seconds = (sum(times[product][index] for product in gaining) for index in (0, 1))
        return MatmulPath("bf16", gaining), {
            "path": "bf16", "compiled": compiled, "gflops": {},
            "bf16_products": sorted([list(a), list(w)] for a, w in gaining), "products": len(times),
            "bf16_speedup": round(float32_seconds / bf16_seconds, 2) if gaining else None}
    speeds = measure_paths(products)
    path = fastest_float32_path(speeds)
    return MatmulPath(path), {"path": path, "compiled": compiled,
                              "gflops": {name: round(value, 1) for name, value in speeds.items()}}


def recorded_matmul_path(choice: Any, setting: str) -> tuple[MatmulPath, dict] | None:
    """The path a run chose at its start (``matmul_path`` in its config.json), to resume it on: the two float32 paths
    round differently, so a resumed run computes as its first part did only on the same path — and only then equals
    an uninterrupted run bit for bit. None when the choice is absent (a run of an older version), unreadable, not
    available here (oneDNN in another build of torch) or not of the ``--matmul`` now asked for (``setting``: float32,
    bf16, or a float32 path named): the path is then measured again, or taken as named."""
    if not isinstance(choice, Mapping) or choice.get("path") not in MATMUL_PATHS:
        return None
    if (choice["path"] == "bf16") != (setting == "bf16"):
        return None
    if setting in FLOAT32_PATHS and choice["path"] != setting:
        return None
    if choice["path"] == "onednn" and not onednn_available():
        return None
    try:
        products = choice.get("bf16_products") if choice["path"] == "bf16" else None
        path = MatmulPath(choice["path"], products)
    except (TypeError, ValueError):
        return None
    return path, dict(choice, kept=True)


def describe_matmul_choice(choice: dict) -> str:
    """One line for the start of a run: the path and, when measured, each path's speed on the run's products."""
    if choice.get("kept"):
        return f"matmul: {choice['path']} (kept from the run's start, so that it continues as it began)"
    if "bf16_products" in choice:
        chosen, total = len(choice["bf16_products"]), choice["products"]
        gain = f", {choice['bf16_speedup']:.1f}x faster on those" if chosen else ""
        return (f"matmul: bf16 on {chosen} of this run's {total} product shapes (measured{gain}), float32 (aten) "
                f"on the {total - chosen} that bfloat16 does not speed up")
    if choice.get("named"):
        return f"matmul: {choice['path']} (as --matmul names it, not measured)"
    if not choice["gflops"]:
        return f"matmul: {choice['path']}"
    speeds = ", ".join(f"{name} {value:.0f}" for name, value in choice["gflops"].items())
    return f"matmul: {choice['path']} (float32 GFLOP/s on this run's products as a step runs them: {speeds})"
