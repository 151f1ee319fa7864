"""Compiled programs: a function of tensors traced once and called as inductor's code, and the helpers that turn
modules into functions of their tensors.

:class:`DirectProgram` compiles one function for one structure and set of shapes of its arguments and then calls
the compiled code directly, without dynamo; :class:`CompiledPerShape` keeps one per input shape of a module's forward
pass. :func:`value_and_grads` takes gradients inside such a program; :func:`as_function` runs a module on tensors
given as arguments (``torch.func.functional_call``).
"""

from __future__ import annotations

import signal
import threading
import types
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import torch
from torch import nn
from torch.func import functional_call
from torch.utils._pytree import tree_map_only


def value_and_grads(loss: Callable[..., torch.Tensor], *args, wrt: tuple[int, ...] = (0,), has_aux: bool = False):
    """``torch.func.grad_and_value(loss, argnums=wrt, has_aux=has_aux)(*args)`` for arguments ``wrt`` that are lists
    of tensors: (the gradients, one list per argument in ``wrt``, or the one list; the loss, detached). With
    ``has_aux`` the loss function returns (loss, aux) and the second item is (loss, aux detached); aux is a tensor or
    nested tuples and lists of them (e.g. the batch statistics of a normalising actor's pass).

    Written with ``torch.autograd.grad`` on detached copies made leaves, which dynamo traces into one graph when
    ``torch._dynamo.config.trace_autograd_ops`` is on (:class:`DirectProgram` turns it on while it traces).
    ``grad_and_value`` also compiles, but with torch 2.13 an autograd Function that runs an opaque operator (the
    oneDNN products, :func:`ilcsan.compute.matmul.onednn_matmul_nt`) then gets a zero gradient for a weight whose
    layer input needs none (tested in ``tests/test_matmul.py``); traced this way its gradients are exact, so compiled
    runs can use every float32 path. A tensor the loss does not reach gets a zero gradient, as with ``torch.func``."""
    args = list(args)
    with torch.enable_grad():
        for index in wrt:
            args[index] = [tensor.detach().requires_grad_() for tensor in args[index]]
        value = loss(*args)
        value, aux = value if has_aux else (value, None)
        leaves = [tensor for index in wrt for tensor in args[index]]
        flat = list(torch.autograd.grad(value, leaves, materialize_grads=True)) if leaves else []
    groups = []
    for index in wrt:
        groups.append(flat[:len(args[index])])
        flat = flat[len(args[index]):]
    grads = tuple(groups) if len(wrt) > 1 else groups[0]
    return grads, ((value.detach(), tree_map_only(torch.Tensor, torch.Tensor.detach, aux)) if has_aux
                   else value.detach())


def as_function(module: nn.Module, tensors: Sequence[torch.Tensor], names: Sequence[str]) -> Callable:
    """``module`` as a function of ``tensors`` (its parameters, in ``names`` order), for ``torch.func``."""
    parameters = dict(zip(names, tensors, strict=True))
    return lambda *args, **kwargs: functional_call(module, parameters, args, kwargs)


def with_own_code(function: Callable) -> Callable:
    """The same function or bound method on a fresh code object, so that dynamo keeps a separate cache for it."""
    bound_to = getattr(function, "__self__", None)
    plain = getattr(function, "__func__", function)
    code = plain.__code__.replace(co_name=f"{plain.__name__}_{id(function):x}")
    own = types.FunctionType(code, plain.__globals__, code.co_name, plain.__defaults__, plain.__closure__)
    own.__kwdefaults__ = plain.__kwdefaults__
    return own if bound_to is None else types.MethodType(own, bound_to)


def tensor_leaves(value, leaves: list[torch.Tensor] | None = None) -> list[torch.Tensor]:
    """The tensors in ``value`` (nested dicts, lists and tuples; anything else skipped), in order."""
    leaves = [] if leaves is None else leaves
    if isinstance(value, torch.Tensor):
        leaves.append(value)
    elif isinstance(value, dict):
        for item in value.values():
            tensor_leaves(item, leaves)
    elif isinstance(value, (list, tuple)):
        for item in value:
            tensor_leaves(item, leaves)
    return leaves


def module_tensors(module: nn.Module) -> list[torch.Tensor]:
    """``module``'s parameters and buffers, persistent or not: the constants (action bounds, masks) are read by a
    program as much as the state is."""
    return [*module.parameters(), *module.buffers()]


class DirectProgram:
    """``function`` for one structure and set of shapes of its arguments: traced once by dynamo, compiled by
    inductor, then inductor's code called directly, without dynamo.

    Entering a dynamo-compiled function has a fixed cost per call (its bytecode fetches every tensor from dicts and
    lists), even without guards, which a batch-1 action or a small update feels. The compiled callable's inputs
    are the traced graph's placeholders, each a tensor the call reached: a leaf of the arguments (dicts, lists and
    tuples of tensors) or one of ``constants``, tensors it reads as attributes that stay the same objects for the
    program's life (parameters and buffers, updated in place; the action bounds). The first call records, by
    identity, which leaf position or which constant each placeholder is; later calls pass the leaves at those
    positions (so new tensors in the same places — a new batch, an optimizer state loaded from a checkpoint — are
    used) and the constants themselves. If a placeholder is neither,
    every call keeps going through dynamo (``direct`` is False), without guards: the program is built for one
    agent and one set of shapes that never change. ``function`` is rebuilt on a fresh code object
    (:func:`with_own_code`), because dynamo keeps its compiled graphs on the code object, so that another program
    (other shapes, other constants) gets its own graphs instead of this one's. Call it under ``torch.no_grad()``
    only.
    """

    def __init__(self, function: Callable, constants: Iterable[torch.Tensor] = ()):
        self.constants = {id(tensor) for tensor in constants}
        self.compiled, self.example_inputs, self.slots, self.fixed, self.output_tuple = None, None, None, None, False
        self.holds_signals = False  # set when compiled: whether the program calls Python operators
        self.traced = torch.compile(with_own_code(function), fullgraph=True, dynamic=False, backend=self._compile,
                                    options={"guard_filter_fn": torch.compiler.skip_all_guards_unsafe})

    @property
    def direct(self) -> bool:
        return self.slots is not None

    def _compile(self, graph: torch.fx.GraphModule, example_inputs: list) -> Callable:
        """Inductor with its C++ wrapper, which calls the kernels from C++ instead of a Python function (less time
        per call, some more at the first compilation)."""
        from torch._inductor.compile_fx import compile_fx

        self.compiled = compile_fx(graph, example_inputs, config_patches={"cpp_wrapper": True})
        self.holds_signals = calls_python_operators(graph)
        self.example_inputs = list(example_inputs)
        return self.compiled

    def _bind(self, leaves: list[torch.Tensor], result) -> None:
        examples, self.example_inputs = self.example_inputs, None
        positions = {id(leaf): index for index, leaf in reversed(list(enumerate(leaves)))}
        slots = [(slot, positions[id(example)]) for slot, example in enumerate(examples) if id(example) in positions]
        if len(slots) + sum(id(example) in self.constants for example in examples) == len(examples):
            self.slots, self.fixed, self.output_tuple = slots, examples, isinstance(result, tuple)

    def __call__(self, *args):
        leaves = tensor_leaves(args)
        if self.slots is None:
            with torch._dynamo.config.patch(trace_autograd_ops=True):  # value_and_grads inside the graph
                result = signals_held(self.traced, list(args)) if self.holds_signals else self.traced(*args)
            if self.example_inputs is not None:
                self._bind(leaves, result)
            return result
        inputs = list(self.fixed)
        for slot, position in self.slots:
            inputs[slot] = leaves[position]
        outputs = signals_held(self.compiled, inputs) if self.holds_signals else self.compiled(*inputs)
        return tuple(outputs) if self.output_tuple else outputs[0]


OPERATOR_NAMESPACE = "ilcsan"
"""The namespace of the operators ilcsan registers (``torch.library.custom_op``), all of them implemented in Python."""


def calls_python_operators(graph: torch.fx.GraphModule) -> bool:
    """Whether a traced graph (its subgraphs included) calls an operator of :data:`OPERATOR_NAMESPACE`."""
    return any(node.op == "call_function" and getattr(node.target, "namespace", None) == OPERATOR_NAMESPACE
               for module in graph.modules() if isinstance(module, torch.fx.GraphModule)
               for node in module.graph.nodes)


HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""The signals a run turns into a KeyboardInterrupt (Ctrl-C; ``kill`` in ``reproduce`` and its workers)."""


def signals_held(compiled: Callable, inputs: list) -> Any:
    """``compiled(*inputs)``, with a :data:`HELD_SIGNALS` signal that arrives meanwhile handed to its Python handler
    only when the call has returned.

    A compiled program (inductor's C++ wrapper) calls Python-implemented operators, the oneDNN products among them,
    through the dispatcher's C interface, which reports an exception raised inside one only as a failed call (a
    RuntimeError): a Ctrl-C landing there would end a run with a traceback instead of a KeyboardInterrupt. So while
    the program runs, a signal is only noted (Python runs signal handlers in the main thread, whichever thread the
    signal reached), and raised again once it has returned. Signals without a Python handler (the default action,
    ignored) are left alone. Only programs that call such operators are run this way (:func:`calls_python_operators`):
    swapping the handlers costs some microseconds per call. A first call, which compiles for a while, is not held
    (Ctrl-C reaches the compilation as it did before)."""
    if threading.current_thread() is not threading.main_thread():  # Python raises KeyboardInterrupt only there
        return compiled(*inputs)
    held = [(number, handler) for number in HELD_SIGNALS if callable(handler := signal.getsignal(number))]
    if not held:
        return compiled(*inputs)
    arrived: list[int] = []
    for number, _ in held:
        signal.signal(number, lambda received, _frame: arrived.append(received))
    try:
        return compiled(*inputs)
    finally:
        for number, handler in held:
            signal.signal(number, handler)
        for number in arrived:
            signal.raise_signal(number)  # now, outside the program, to the handler it was meant for


class CompiledPerShape:
    """A module's forward through one :class:`DirectProgram` per shape and dtype of its inputs: acting (K, 1, N),
    evaluation (K, E, N) and a training method's own batches each get their own program. Call it under
    ``torch.no_grad()`` only."""

    def __init__(self, module: nn.Module, function: Callable | None = None):
        self.module, self.programs = module, {}
        self.function = function or module.forward
        """What runs: the module's forward, or a function of its inputs that reads the module (e.g. its readout)."""

    def __call__(self, *inputs: torch.Tensor) -> torch.Tensor:
        inputs = tuple(x.contiguous() for x in inputs)  # a program assumes the layout it was compiled for
        key = tuple((x.shape, x.dtype) for x in inputs)
        program = self.programs.get(key)
        if program is None:
            program = self.programs[key] = DirectProgram(self.function, module_tensors(self.module))
        return program(*inputs)


def as_program(function: Callable, constants: Sequence[torch.Tensor], compile: bool) -> Callable:
    """``function`` as one :class:`DirectProgram` (``constants`` the tensors it reads as attributes) when
    ``compile``, else ``function`` itself, run eagerly: one definition either way."""
    return DirectProgram(function, constants) if compile else function


COMPILE_RECOMPILE_LIMIT = 64


def prepare_compilation() -> None:
    """Free the graphs of earlier agents in this process and allow enough variants per function.

    torch.compile guards each graph on the module instance, grad mode and input shapes; one agent needs
    about three variants per forward (acting, training, target), so a process that builds agent after agent
    (``ilcsan reproduce`` workers, benchmarks) would exhaust dynamo's default limit of 8 and silently fall
    back to eager execution.
    """
    import torch._dynamo

    torch._dynamo.reset()
    torch._dynamo.config.recompile_limit = max(torch._dynamo.config.recompile_limit, COMPILE_RECOMPILE_LIMIT)
