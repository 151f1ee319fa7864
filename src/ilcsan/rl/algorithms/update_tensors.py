"""How an update program reaches an agent's tensors.

An update is a pure function of the agent's tensors, run eagerly or as one compiled program
(:func:`~ilcsan.compute.programs.as_program`). A compiled program reads a module's own tensors as constants and tells
its inputs from them by identity, so the tensors an update reads and writes are passed in as *views*: other tensor
objects on the same storage, made once per module and kept for the agent's life (a checkpoint loads into them in
place). Every pass of a network inside an update runs on such views, through ``torch.func.functional_call``
(:func:`~ilcsan.compute.programs.as_function`): its parameters, then its persistent buffers (a normalisation's running
statistics, which the update writes in place as Adam writes its state).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn

from ...compute.programs import as_function
from ...runs.checkpoint import module_state


def persistent_buffers(module: nn.Module) -> dict[str, torch.Tensor]:
    """``module``'s persistent buffers by name: its :func:`~ilcsan.runs.checkpoint.module_state` without the
    parameters (state such as a normalisation's running statistics; none for an actor without normalisation)."""
    parameters = {name for name, _ in module.named_parameters()}
    return {name: tensor for name, tensor in module_state(module).items() if name not in parameters}


class UpdateTensors:
    """The views of an agent's modules that its update programs take (the module docstring), made once per module."""

    def __init__(self):
        self._parameters: dict[int, list[torch.Tensor]] = {}
        self._buffers: dict[int, list[torch.Tensor]] = {}
        self._names: dict[int, list[str]] = {}

    def parameters(self, module: nn.Module) -> list[torch.Tensor]:
        """Detached views of ``module``'s parameters (a target network's: no Adam holds them)."""
        views = self._parameters.get(id(module))
        if views is None:
            views = self._parameters[id(module)] = [parameter.detach() for parameter in module.parameters()]
        return views

    def buffers(self, module: nn.Module) -> list[torch.Tensor]:
        """Detached views of ``module``'s :func:`persistent_buffers`."""
        views = self._buffers.get(id(module))
        if views is None:
            views = self._buffers[id(module)] = [buffer.detach() for buffer in persistent_buffers(module).values()]
        return views

    def stateful(self, module: nn.Module, parameters: list[torch.Tensor], buffers: list[torch.Tensor]) -> Callable:
        """``module`` as a function of its parameters and persistent buffers passed in: how every pass of an actor
        inside an update reads its state."""
        names = self._names.get(id(module))
        if names is None:
            names = self._names[id(module)] = ([name for name, _ in module.named_parameters()]
                                               + list(persistent_buffers(module)))
        return as_function(module, [*parameters, *buffers], names)
