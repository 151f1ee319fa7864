"""The matmul path of a run, chosen by measuring the run's own products at its start, and kept when it resumes."""

from __future__ import annotations

from collections.abc import Mapping
from itertools import pairwise
from typing import Any

import torch

from ..compute.matmul import (
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
from ..config import PROXY_HIDDEN, SPIKING_ENCODERS, RunConfig
from ..snn.diagnostics import DIAGNOSTIC_STATES


def run_products(config: RunConfig, state_dim: int, action_dim: int) -> list[Product]:
    """The (a, w) shapes of the products of this run (:data:`~ilcsan.compute.matmul.Product`), repeated as a step
    repeats them: for each actor layer the three products of an update over T·B rows and the forward product of
    acting (T rows), of evaluation (T·E rows), of the diagnostics at each evaluation (T·1000 rows) and, with Proxy
    Target, of the proxy's regression targets (T·B·K_proxy rows), T being 1 for DAN and for a first layer whose
    input is not a spike train; the three products of every
    critic layer for the 2K critics of the critic loss and for the K first critics of the actor loss; and with
    Proxy Target, those of the proxy's layers."""
    seeds, td3, actor = len(config.seeds), config.td3, config.actor
    batch, proxy = td3.batch_size, td3.target_actor == "proxy"
    timesteps = actor.timesteps if actor.network == "spiking" else 1
    forward_rows = [1, config.eval_episodes, DIAGNOSTIC_STATES] + ([batch * td3.proxy_iterations] if proxy else [])
    products = []
    for index, (d_in, d_out) in enumerate(pairwise(actor.layer_sizes(state_dim, action_dim))):
        steps = timesteps if index > 0 or actor.encoder in SPIKING_ENCODERS else 1
        products += layer_products(seeds, steps * batch, d_in, d_out)
        products += [layer_products(seeds, steps * rows, d_in, d_out)[0] for rows in forward_rows]
    critic = [state_dim + action_dim, *td3.critic_hidden, 1]
    for members in (2 * seeds, seeds):
        products += [p for d_in, d_out in pairwise(critic) for p in layer_products(members, batch, d_in, d_out)]
    if proxy:
        sizes = [state_dim, *PROXY_HIDDEN, action_dim]
        products += [p for d_in, d_out in pairwise(sizes) for p in layer_products(seeds, batch, d_in, d_out)]
    return products


def choose_matmul_path(config: RunConfig, state_dim: int, action_dim: int) -> tuple[MatmulPath, dict]:
    """The matmul path of the run's networks (:mod:`ilcsan.compute.matmul`) and what was chosen, for config.json and
    the start-up line. float32: the faster float32 path on the run's own products, measured now. bf16: bfloat16 for
    the products it computes faster, measured now as the run will compute them (casts fused when compiled), float32
    (``aten``) for the others."""
    if torch.device(config.device).type != "cpu":
        return MatmulPath("aten"), {"path": "aten", "gflops": {}}
    products, compiled = run_products(config, state_dim, action_dim), config.compiles()
    if config.matmul == "bf16":
        times = product_times(products, fused_casts=compiled)
        gaining = gaining_products(times)
        float32_seconds, bf16_seconds = (sum(times[product][index] for product in gaining) for index in (0, 1))
        return MatmulPath("bf16", gaining), {
            "path": "bf16", "compiled": compiled, "gflops": {},
            "bf16_products": sorted([list(a), list(w)] for a, w in gaining), "products": len(times),
            "bf16_speedup": round(float32_seconds / bf16_seconds, 2) if gaining else None}
    speeds = measure_paths(products, seconds=0.05)
    path = fastest_float32_path(speeds)
    return MatmulPath(path), {"path": path, "compiled": compiled,
                              "gflops": {name: round(value, 1) for name, value in speeds.items()}}


def recorded_matmul_path(choice: Any, setting: str) -> tuple[MatmulPath, dict] | None:
    """The path a run chose at its start (``matmul_path`` in its config.json), to resume it on: the two float32 paths
    round differently, so a resumed run computes as its first part did only on the same path — and only then equals
    an uninterrupted run bit for bit. None when the choice is absent (a run of an older version), unreadable, not
    available here (oneDNN in another build of torch) or not of the ``--matmul`` now asked for (``setting``: float32
    or bf16): the path is then measured again."""
    if not isinstance(choice, Mapping) or choice.get("path") not in MATMUL_PATHS:
        return None
    if (choice["path"] == "bf16") != (setting == "bf16"):
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
    if not choice["gflops"]:
        return f"matmul: {choice['path']}"
    speeds = ", ".join(f"{name} {value:.0f}" for name, value in choice["gflops"].items())
    return f"matmul: {choice['path']} (float32 GFLOP/s on this run's products: {speeds})"
