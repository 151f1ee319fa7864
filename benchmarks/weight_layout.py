"""Does the weight's memory layout matter? PyTorch's (out, in) against (in, out), per product of a run: prints one
Markdown table.

A linear layer stores its weight (out, in) and multiplies by its transpose; MKL receives the transposition as a flag.
For each product shape of an ILC-SAN and a DAN update (the forward product, the input gradient and the weight
gradient, batch 100 × T rows) and of the batch-1 action (T = 5 rows, forward only), the median time of each layout,
one thread, and their ratio. Run it on an idle machine:

    .venv/bin/python benchmarks/weight_layout.py
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).parent))
from speed import cpu_model, median_call_us  # noqa: E402

SHAPES = (("ILC-SAN Hopper, layer 1", 500, 110, 256), ("ILC-SAN, layer 2", 500, 256, 256),
          ("ILC-SAN Hopper, output populations", 500, 256, 30), ("ILC-SAN Ant, layer 1", 500, 1110, 256),
          ("DAN Ant, layer 1", 100, 111, 256), ("DAN, layer 2", 100, 256, 256), ("critic Ant, layer 1", 100, 119, 256))
"""(label, rows, in, out) of the update's products: rows = batch 100 × T time steps (T = 5 for spiking layers)."""
ACTING = (("act: ILC-SAN Ant, layer 1", 5, 1110, 256), ("act: ILC-SAN, layer 2", 5, 256, 256),
          ("act: ILC-SAN Ant, output populations", 5, 256, 80))
"""The batch-1 action's products (forward only)."""


def layout_times(rows: int, n_in: int, n_out: int, calls: int, backward: bool) -> tuple[float, float]:
    """Median µs of the forward product (and, with ``backward``, the input and weight gradients) summed, with the
    weight stored (out, in) and (in, out)."""
    x, grad = torch.randn(rows, n_in), torch.randn(rows, n_out)
    weight = torch.randn(n_out, n_in)
    transposed = weight.t().contiguous()
    out_in = [lambda: torch.mm(x, weight.t())]
    in_out = [lambda: torch.mm(x, transposed)]
    if backward:
        out_in += [lambda: torch.mm(grad, weight), lambda: torch.mm(grad.t(), x)]
        in_out += [lambda: torch.mm(grad, transposed.t()), lambda: torch.mm(x.t(), grad)]
    return (sum(median_call_us(f, calls, calls // 5) for f in out_in),
            sum(median_call_us(f, calls, calls // 5) for f in in_out))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=400, help="timed calls per product")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"CPU: {cpu_model()} · torch {torch.__version__} · 1 thread · float32, default matmul path\n")
    print("| product | rows × in × out | (out, in) µs | (in, out) µs | (out, in) / (in, out) |")
    print("|---|---|---|---|---|")
    for label, rows, n_in, n_out in SHAPES + ACTING:
        out_in, in_out = layout_times(rows, n_in, n_out, args.calls, backward=(label, rows, n_in, n_out) in SHAPES)
        print(f"| {label} | {rows} × {n_in} × {n_out} | {out_in:.1f} | {in_out:.1f} | {out_in / in_out:.2f} |")
    print("\nUpdate rows: forward + input gradient + weight gradient; act rows: forward only.")


if __name__ == "__main__":
    main()
