"""Adam (Kingma & Ba 2015), the one optimiser of every network a run trains: its rule and its state.

:func:`adam_` is the step, a few lines of tensor arithmetic that the update program runs eager or compiles whole;
:class:`Adam` holds the moments and step counts of one module's parameters and gives and takes each seed's slice of
them for checkpoints, in the layout ``torch.optim.Adam`` uses (``exp_avg``, ``exp_avg_sq``, ``step``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from torch import nn

from ..errors import UserError

ADAM_BETAS = (0.9, 0.999)
ADAM_EPS = 1e-8
"""torch.optim.Adam's defaults."""


def adam_(params: Sequence[torch.Tensor], grads: Sequence[torch.Tensor], averages: Sequence[torch.Tensor],
          squares: Sequence[torch.Tensor], steps: Sequence[torch.Tensor], lr: float) -> None:
    """One Adam step in place, torch.optim.Adam's rule (no weight decay, no amsgrad):
    t ← t + 1;  m ← β₁m + (1 − β₁)g;  v ← β₂v + (1 − β₂)g²;  θ ← θ − lr/(1 − β₁ᵗ) · m / (√v / √(1 − β₂ᵗ) + ε).

    Every parameter of one optimiser steps together, so their counts are equal and the two bias corrections are
    computed once, from all the counts (their maximum). Written per parameter, inductor would put two scalar
    ``pow`` calls into every vectorised iteration of every parameter's loop; computed once, into a buffer of its own
    (a value that reads several buffers and is used by several loops is), the loops only read it.
    """
    beta1, beta2 = ADAM_BETAS
    for step in steps:
        step.add_(1.0)
    counts = torch.stack(list(steps))
    step_size = (lr / (1.0 - beta1 ** counts)).amax()
    root_correction2 = (1.0 - beta2 ** counts).sqrt().amax()
    for param, grad, average, square in zip(params, grads, averages, squares, strict=True):
        average.lerp_(grad, 1.0 - beta1)
        square.mul_(beta2).addcmul_(grad, grad, value=1.0 - beta2)
        param.sub_(step_size * average / (square.sqrt() / root_correction2 + ADAM_EPS))


class Adam:
    """Adam's state for the parameters of ``module`` at learning rate ``lr``: per parameter its first and second
    moments (zeros) and its step count (0, a float32 scalar), created with the module.

    ``tensors()`` are what :func:`adam_` steps (the update program reads them anew at each call, since loading a
    checkpoint replaces them), ``views`` the parameters it steps.
    """

    def __init__(self, module: nn.Module, lr: float):
        self.lr = lr
        named = list(module.named_parameters())
        self.names = [name for name, _ in named]
        self.parameters = [param for _, param in named]
        self.views = [param.detach() for param in self.parameters]
        self.averages = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.parameters]
        self.squares = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.parameters]
        self.steps = [torch.zeros((), dtype=torch.float32, device=p.device) for p in self.parameters]

    def tensors(self) -> tuple[list[torch.Tensor], list[torch.Tensor], list[torch.Tensor]]:
        """(first moments, second moments, step counts), one per parameter in module order."""
        return self.averages, self.squares, self.steps

    # ---------------------------------------------------------------------------- checkpoints
    def seed_state(self, index: int, rows: int) -> dict[str, dict[str, torch.Tensor]]:
        """Seed ``index``'s slice (rows [rows·index, rows·(index + 1)) of every moment; the step count, shared by all
        seeds, whole), by parameter name, on the CPU: what a one-seed checkpoint holds."""
        def cut(value: torch.Tensor) -> torch.Tensor:
            part = value if value.dim() == 0 else value[rows * index: rows * (index + 1)]
            return part.detach().cpu().clone()

        return {name: {"step": cut(step), "exp_avg": cut(average), "exp_avg_sq": cut(square)}
                for name, average, square, step in zip(self.names, self.averages, self.squares, self.steps,
                                                       strict=True)}

    def load_seed_states(self, states: Sequence[dict[str, dict[str, Any]]]) -> None:
        """Stack the seeds' :meth:`seed_state` slices back; a parameter missing from any of them (a checkpoint made
        before its first step) keeps zero moments and a zero count."""
        for index, (name, param) in enumerate(zip(self.names, self.parameters, strict=True)):
            if not all(name in state for state in states):
                continue
            entry = states[0][name]
            step = torch.as_tensor(entry["step"]).clone().to(device=param.device, dtype=torch.float32)
            moments = []
            for key in ("exp_avg", "exp_avg_sq"):
                stacked = torch.cat([state[name][key] for state in states]).to(param.device)
                if stacked.shape != param.shape:
                    raise UserError(f"the checkpoint's optimizer state {name!r} has shape {tuple(stacked.shape)}, "
                                    f"this run needs {tuple(param.shape)}: it belongs to another actor or task")
                moments.append(stacked)
            self.averages[index], self.squares[index] = moments
            self.steps[index] = step
