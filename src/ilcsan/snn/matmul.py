"""The matrix products of every network, on the path that is fastest on this CPU, chosen by measurement.

Every synaptic layer, critic layer and their gradients is one batched product ``a @ wᵀ`` per ensemble member,
(K, R, in) × (K, out, in) → (K, R, out) (:func:`ensemble_matmul`). It runs on one of :data:`MATMUL_PATHS`:

``aten``    ``torch.bmm``: PyTorch's CPU BLAS, Intel MKL on x86. MKL runs its AVX2 kernels on AMD CPUs, so on
            an AVX-512 AMD CPU whose vector units are 512 bits wide it reaches about half of the peak.
``onednn``  oneDNN's matmul primitive (``torch.ops.mkldnn._linear_pointwise``), float32, which uses AVX-512
            (and AMX's float32 paths where present) on both vendors.
``bf16``    ``torch.bmm`` on bfloat16 copies of both operands, the product rounded to bfloat16 and returned as
            float32 (AVX512-BF16 or AMX kernels through oneDNN). Not float32: chosen only by ``--matmul bf16``.

:func:`measure_paths` times the float32 paths on a run's own shapes (forward and both backward products of
every layer) and :func:`fastest_float32_path` picks the quicker; the two agree to float32 rounding (tested).
A compiled update program runs on :data:`COMPILABLE_PATHS` only. The path is a process setting
(:func:`use_matmul_path`), read when a program is compiled, so it is set before an agent is built, like
torch's own matmul precision.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import torch

MATMUL_PATHS = ("aten", "onednn", "bf16")
FLOAT32_PATHS = ("aten", "onednn")
COMPILABLE_PATHS = ("aten", "bf16")
"""The paths a compiled update program may use. torch 2.13 compiles the oneDNN operator into the update program,
but the program's gradient of a first layer's weight comes out as zero (tested: ``tests/test_matmul.py``), so
compiled runs keep to these and oneDNN serves eager runs only."""

_path = "aten"


def use_matmul_path(path: str) -> None:
    """Run every :func:`ensemble_matmul` of this process on ``path`` (one of :data:`MATMUL_PATHS`)."""
    global _path
    if path not in MATMUL_PATHS:
        raise ValueError(f"unknown matmul path {path!r}; choose one of {', '.join(MATMUL_PATHS)}")
    _path = path


def matmul_path() -> str:
    """The path :func:`ensemble_matmul` runs on in this process."""
    return _path


def onednn_available() -> bool:
    return torch.backends.mkldnn.is_available() and hasattr(torch.ops.mkldnn, "_linear_pointwise")


@torch.library.custom_op("ilcsan::onednn_matmul_nt", mutates_args=())
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


def ensemble_matmul(a: torch.Tensor, w: torch.Tensor, path: str | None = None) -> torch.Tensor:
    """a @ wᵀ per ensemble member, (K, R, in) × (K, out, in) → (K, R, out), on ``path`` (default: this
    process's, :func:`use_matmul_path`). Not differentiable by itself: callers write their backward with it."""
    path = path or _path
    if path == "onednn":
        return onednn_matmul_nt(a.detach(), w.detach())
    if path == "bf16":
        return torch.bmm(a.to(torch.bfloat16), w.to(torch.bfloat16).transpose(1, 2)).to(a.dtype)
    return torch.bmm(a, w.transpose(1, 2))


def layer_products(ensemble: int, rows: int, d_in: int, d_out: int) -> list[tuple[tuple[int, ...], tuple[int, ...]]]:
    """The three products of a layer y = x Wᵀ over ``rows`` inputs, as (a, w) shapes for ``a @ wᵀ``: the
    forward pass, ∂L/∂x = g W and ∂L/∂W = gᵀ x."""
    return [((ensemble, rows, d_in), (ensemble, d_out, d_in)), ((ensemble, rows, d_out), (ensemble, d_in, d_out)),
            ((ensemble, d_out, rows), (ensemble, d_in, rows))]


def measure_paths(products: Sequence[tuple[tuple[int, ...], tuple[int, ...]]], paths: Sequence[str] = FLOAT32_PATHS,
                  seconds: float = 0.15) -> dict[str, float]:
    """GFLOP/s of each path on ``products`` ((a shape, w shape) pairs run back to back), ~``seconds`` each.

    The paths are timed in alternation, several rounds, keeping each path's best round (the least disturbed
    by other work on the machine)."""
    generator = torch.Generator().manual_seed(0)
    operands = [(torch.randn(a, generator=generator), torch.randn(w, generator=generator)) for a, w in products]
    flops = sum(2.0 * a[0] * a[1] * a[2] * w[1] for a, w in products)
    usable = [path for path in paths if path != "onednn" or onednn_available()]
    best = dict.fromkeys(usable, float("inf"))
    for path in usable:  # warm-up: oneDNN builds its primitives on the first call of each shape
        for a, w in operands:
            ensemble_matmul(a, w, path)
    rounds, deadline = 0, time.perf_counter() + seconds * len(usable)
    while rounds < 3 or (time.perf_counter() < deadline and rounds < 50):
        for path in usable:
            start = time.perf_counter()
            for a, w in operands:
                ensemble_matmul(a, w, path)
            best[path] = min(best[path], time.perf_counter() - start)
        rounds += 1
    return {path: flops / elapsed / 1e9 for path, elapsed in best.items()}


def fastest_float32_path(speeds: dict[str, float], compiled: bool = False) -> str:
    """The float32 path with the highest GFLOP/s in ``speeds`` (``aten`` on a tie or when alone), among the
    :data:`COMPILABLE_PATHS` when the run is compiled."""
    allowed = [path for path in FLOAT32_PATHS if path in COMPILABLE_PATHS or not compiled]
    candidates = {path: speed for path, speed in speeds.items() if path in allowed}
    return max(candidates, key=lambda path: (candidates[path], path == "aten"), default="aten")
