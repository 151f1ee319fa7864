"""The matrix products of every network, on the path that is fastest on this CPU, chosen by measurement.

Every synaptic layer, critic layer and their gradients is one batched product ``a @ wᵀ`` per ensemble member,
(K, R, in) × (K, out, in) → (K, R, out) (:func:`ensemble_matmul`). It runs on one of :data:`MATMUL_PATHS`:

``aten``    ``torch.bmm``: PyTorch's CPU BLAS, Intel MKL on x86. MKL runs its AVX2 kernels on AMD CPUs, so on
            an AVX-512 AMD CPU it can reach only part of the peak.
``onednn``  oneDNN's matmul primitive (``torch.ops.mkldnn._linear_pointwise``), float32, which uses AVX-512
            (and AMX's float32 paths where present) on both vendors.
``bf16``    ``torch.bmm`` on contiguous bfloat16 copies of both operands (``a`` and ``wᵀ``), the product rounded to
            bfloat16 and returned as float32 (AMX or AVX512-BF16 kernels through oneDNN). Not float32: chosen only
            by ``--matmul bf16``. A bfloat16 call has a fixed cost that small products do not repay, so a bf16 run
            keeps its small products in float32: it times each of its products both ways at start
            (:func:`product_times`) and runs in bfloat16 only those that gain (``MatmulPath("bf16", products)``).

A network is built with its :class:`MatmulPath`, an explicit object its layers keep (nothing global): each product's
path is read when the product runs, so a compiled program bakes in the one it was traced with.
:func:`measure_paths` times the float32 paths on a run's own shapes (forward and both backward products of every
layer), each weighted by how often a training step computes it, and :func:`fastest_float32_path` picks the quicker;
the two agree to float32 rounding (tested), eager and inside a compiled update program.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass

import torch

from .programs import OPERATOR_NAMESPACE

MATMUL_PATHS = ("aten", "onednn", "bf16")
FLOAT32_PATHS = ("aten", "onednn")
Product = tuple[tuple[int, ...], tuple[int, ...]]
"""The shapes (a, w) of a product ``a @ wᵀ``: ((K, R, in), (K, out, in))."""

BF16_GAIN = 0.9
"""A bf16 run computes a product in bfloat16 only when that takes at most this fraction of its float32 time: where
the two are about as fast, the exact one."""



@dataclass(frozen=True)
class MatmulPath:
    """Where a network's products run: ``kind``, one of :data:`MATMUL_PATHS`; with ``bf16``, ``bf16_products`` are the
    product shapes computed in bfloat16, the others running on ``aten`` (None: all)."""

    kind: str = "aten"
    bf16_products: frozenset[Product] | None = None

    def __post_init__(self) -> None:
        if self.kind not in MATMUL_PATHS:
            raise ValueError(f"unknown matmul path {self.kind!r}; choose one of {', '.join(MATMUL_PATHS)}")
        if self.bf16_products is not None:
            object.__setattr__(self, "bf16_products", frozenset(
                (tuple(a), tuple(w)) for a, w in self.bf16_products))

    def product_path(self, a_shape: Sequence[int], w_shape: Sequence[int]) -> str:
        """The path a product of these shapes runs on. Shapes are static in a compiled program, so the choice is
        made once, when it is traced."""
        if (self.kind == "bf16" and self.bf16_products is not None
                and (tuple(a_shape), tuple(w_shape)) not in self.bf16_products):
            return "aten"
        return self.kind


DEFAULT_MATMUL = MatmulPath()
"""torch's own float32 products (``aten``): what a network runs on unless a run chose another path."""


def onednn_available() -> bool:
    return torch.backends.mkldnn.is_available() and hasattr(torch.ops.mkldnn, "_linear_pointwise")


@torch.library.custom_op(f"{OPERATOR_NAMESPACE}::onednn_matmul_nt", mutates_args=())
def onednn_matmul_nt(a: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """a @ wᵀ for every ensemble member through oneDNN: (K, R, in) × (K, out, in) → (K, R, out), float32.

    An opaque operator to the compiler (inductor's own lowering of oneDNN's linear expects prepacked weights)
    without a derivative: the autograd Functions that call it write their backward with it."""
    a, w = a.contiguous(), w.contiguous()
    return torch.stack([torch.ops.mkldnn._linear_pointwise(a[k], w[k], None, "none", [], "")
                        for k in range(a.shape[0])])


@onednn_matmul_nt.register_fake
def _(a: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    return a.new_empty(a.shape[0], a.shape[1], w.shape[1])


def ensemble_matmul(a: torch.Tensor, w: torch.Tensor, path: str = "aten") -> torch.Tensor:
    """a @ wᵀ per ensemble member, (K, R, in) × (K, out, in) → (K, R, out), on ``path`` (one of
    :data:`MATMUL_PATHS`). Not differentiable by itself: callers write their backward with it."""
    if path == "onednn":
        return onednn_matmul_nt(a.detach(), w.detach())
    if path == "bf16":
        return torch.bmm(*bf16_operands(a, w)).to(a.dtype)
    return torch.bmm(a, w.transpose(1, 2))


def bf16_operands(a: torch.Tensor, w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``a`` and ``wᵀ`` as contiguous bfloat16 tensors, each cast in one pass. Handed a transposed bfloat16
    operand, torch's bmm copies it into this layout first (an ``aten::contiguous`` per product); made here, the
    layout comes with the cast, which a compiled program fuses into the kernel that computes the operand."""
    return (a.to(torch.bfloat16, memory_format=torch.contiguous_format),
            w.transpose(1, 2).to(torch.bfloat16, memory_format=torch.contiguous_format))


def product_call(a: torch.Tensor, w: torch.Tensor, path: str, fused_casts: bool = False) -> Callable[[], torch.Tensor]:
    """A call computing ``a @ wᵀ`` on ``path`` as a run does, for timing: on ``bf16`` with ``fused_casts`` the
    operands are cast beforehand, as a compiled program computes them (:func:`bf16_operands`); otherwise the
    call casts them, as an eager run does."""
    if path == "bf16" and fused_casts:
        a16, wt16 = bf16_operands(a, w)
        return lambda: torch.bmm(a16, wt16)
    return lambda: ensemble_matmul(a, w, path)


def time_calls(calls: dict[str, Sequence[Callable[[], object]]], seconds: float) -> dict[str, float]:
    """The best time of each entry's calls run back to back, in seconds. The entries are timed in alternation,
    several rounds (at least 3, at most 50, for about ``seconds`` each), keeping each entry's best round (the
    least disturbed by other work on the machine); a warm-up call each first (oneDNN builds its primitives on
    the first call of each shape)."""
    for group in calls.values():
        for call in group:
            call()
    best = dict.fromkeys(calls, float("inf"))
    rounds, deadline = 0, time.perf_counter() + seconds * len(calls)
    while rounds < 3 or (time.perf_counter() < deadline and rounds < 50):
        for name, group in calls.items():
            start = time.perf_counter()
            for call in group:
                call()
            best[name] = min(best[name], time.perf_counter() - start)
        rounds += 1
    return best


def product_times(products: Collection[Product], fused_casts: bool, seconds: float = 0.002,
                  paths: Sequence[str] = ("aten", "bf16")) -> dict[Product, tuple[float, ...]]:
    """Each distinct product's time in seconds on each of ``paths`` (default: float32 on ``aten``, then bfloat16), in
    that order, timed as the run will compute it (:func:`product_call`), ~``seconds`` per product and path; the
    products worth computing in bfloat16 are those with ``bf16 <= BF16_GAIN * float32`` (:func:`gaining_products`)."""
    generator = torch.Generator().manual_seed(0)
    times = {}
    for a_shape, w_shape in dict.fromkeys(products):
        a, w = torch.randn(a_shape, generator=generator), torch.randn(w_shape, generator=generator)
        best = time_calls({path: [product_call(a, w, path, fused_casts)] for path in paths}, seconds)
        times[(tuple(a_shape), tuple(w_shape))] = tuple(best[path] for path in paths)
    return times


def gaining_products(times: dict[Product, tuple[float, float]]) -> set[Product]:
    """The products of :func:`product_times`'s timings that bfloat16 computes in at most ``BF16_GAIN`` of
    their float32 time."""
    return {product for product, (float32, bf16) in times.items() if bf16 <= BF16_GAIN * float32}


def layer_products(ensemble: int, rows: int, d_in: int, d_out: int) -> list[Product]:
    """The three products of a layer y = x Wᵀ over ``rows`` inputs, as (a, w) shapes for ``a @ wᵀ``: the
    forward pass, ∂L/∂x = g W and ∂L/∂W = gᵀ x."""
    return [((ensemble, rows, d_in), (ensemble, d_out, d_in)), ((ensemble, rows, d_out), (ensemble, d_in, d_out)),
            ((ensemble, d_out, rows), (ensemble, d_in, rows))]


def measure_paths(products: Mapping[Product, float] | Sequence[Product], paths: Sequence[str] = FLOAT32_PATHS,
                  seconds: float = 0.003) -> dict[str, float]:
    """GFLOP/s of each path on ``products`` as a run repeats them: with a mapping, each product counts as often as its
    value says (:func:`~ilcsan.rl.matmul_choice.run_products`: times per environment step), a sequence counts each
    entry once. Each distinct product is timed on every path in alternation (:func:`product_times`, ~``seconds``
    each), so a path is judged by Σ count × time: the small products a step runs every time (one action: T rows) weigh
    as they do in training, not as little as their share of the flops."""
    counts = products if isinstance(products, Mapping) else Counter((tuple(a), tuple(w)) for a, w in products)
    usable = [path for path in paths if path != "onednn" or onednn_available()]
    times = product_times(counts, fused_casts=False, seconds=seconds, paths=usable)
    flops = sum(count * product_flops(product) for product, count in counts.items())
    return {path: flops / sum(count * times[product][index] for product, count in counts.items()) / 1e9
            for index, path in enumerate(usable)}


def product_flops(product: Product) -> float:
    """Floating-point operations of one product ``a @ wᵀ``: 2 · K · R · in · out."""
    (members, rows, d_in), (_, d_out, _) = product
    return 2.0 * members * rows * d_in * d_out


def fastest_float32_path(speeds: dict[str, float]) -> str:
    """The float32 path with the highest GFLOP/s in ``speeds`` (``aten`` on a tie or when alone)."""
    candidates = {path: speed for path, speed in speeds.items() if path in FLOAT32_PATHS}
    return max(candidates, key=lambda path: (candidates[path], path == "aten"), default="aten")
