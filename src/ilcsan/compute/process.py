"""What a run sets in its process: torch's thread count and float32 matmul precision, and flushing denormal floats.

:class:`ProcessSettings` records them before a run and gives them back after it.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


def set_matmul_precision(name: str, device: str = "cpu") -> None:
    """Apply ``--matmul`` to torch's float32 matmul precision (a global setting): on CUDA, ``bf16`` lets float32
    products use TF32/bf16 tensor cores ("medium"); on a CPU every float32 product stays float32 ("highest"; there
    the bf16 path casts the products it chooses itself, :mod:`ilcsan.compute.matmul`: "medium" would make oneDNN
    round every float32 product, the small ones too, which bfloat16 computes slower)."""
    cuda_bf16 = name == "bf16" and torch.device(device).type == "cuda"
    torch.set_float32_matmul_precision("medium" if cuda_bf16 else "highest")


@dataclass(frozen=True)
class ProcessSettings:
    """What a run changes in its process, as it was before: this thread's denormal flag, torch's thread count and
    float32 matmul precision."""

    denormals_flushed: bool
    threads: int
    precision: str

    @classmethod
    def now(cls) -> ProcessSettings:
        return cls(denormals_flushed(), torch.get_num_threads(), torch.get_float32_matmul_precision())

    def restore(self) -> None:
        """Give the process these settings back."""
        flush_denormals(self.denormals_flushed)
        torch.set_num_threads(self.threads)
        torch.set_float32_matmul_precision(self.precision)


def apply_to_process(threads: int | None, matmul: str, device: str) -> None:
    """``--threads``, ``--matmul`` (:func:`set_matmul_precision`) and flushing denormal floats to zero
    (:func:`flush_denormals`) for this process."""
    flush_denormals()
    if threads is not None:
        torch.set_num_threads(threads)
    set_matmul_precision(matmul, device)


def denormals_flushed() -> bool:
    """Whether this thread flushes denormal floats to zero now: a float64 → float32 conversion of 1e-39 tells."""
    return float(torch.tensor(1e-39, dtype=torch.float64).to(torch.float32)) == 0.0


def flush_denormals(on: bool = True) -> bool:
    """Treat float32 values below 1.2e-38 (denormals) as zero in this thread (x86 FTZ/DAZ) and in the threads
    it starts later (``on=False``: keep them again); returns whether the CPU supports it.

    The flag is per thread and a new thread inherits it, so it reaches torch's intra-op worker threads only if
    set before the process's first multi-threaded operation creates them (set after, a worker's share of a product
    keeps its denormals). A run sets it before any torch work, once its task builds (:func:`apply_to_process`), and
    the trainer gives this thread its earlier setting back when it closes (worker threads started meanwhile keep
    it); from Python, call this before any multi-threaded torch work.

    Why: Adam's moments m and v of a weight whose gradient is (nearly) zero — the input weights of a neuron that
    stays silent, a dead ReLU of an MLP (a critic, a training method's own network) — decay geometrically (×β₁, ×β₂
    per update) into the denormal range within a few hundred updates and stay there while tiny gradients keep
    arriving. Each arithmetic operation on a denormal then takes a microcode assist, many times slower than a normal
    one, and a large share of the moments of such an MLP can be denormal after a thousand updates. Flushing them
    changes an Adam step by less than 1e-30 (m̂ / (√v̂ + ε) with ε = 1e-8 and |m̂| < 1.2e-38), far below a
    weight's last bit.
    """
    return torch.set_flush_denormal(on)
