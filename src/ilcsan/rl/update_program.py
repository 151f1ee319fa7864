"""TD3's update as one program: pure functions of the parameter tensors, compiled whole.

The eager update (:meth:`ilcsan.rl.td3.TD3Agent.update`) is hundreds of small PyTorch calls, each paying
Python and dispatcher cost. Here the same update is written as a function of plain tensors — the networks
run through ``torch.func.functional_call``, the gradients come from ``torch.autograd.grad`` on fresh leaves
(:func:`value_and_grads`), Adam and the Polyak averages are a few lines of tensor arithmetic — and
``torch.compile(fullgraph=True)`` turns each of its two variants into one program with no Python between
operations:

* ``critic``: y = r + γ(1 − d) min_j Q'_j(s', clip(π'(s') + clip(σ̃ε, −c, c))), one critic Adam step;
* ``critic+actor`` (every ``policy_delay``-th update): the same, then the actor's Adam step on −Q_1(s, π(s))
  with the *updated* critic (NoisySAN: on its noisy loss, with σ_d's Adam step beside the actor's), then
  θ' ← τθ + (1 − τ)θ' for the target actor and the target critic.

Both read and write the agent's own tensors in place — parameters, target parameters and the state of its
``torch.optim.Adam`` optimizers (``exp_avg``, ``exp_avg_sq``, ``step``) — so checkpoints, resuming and the
eager path see exactly what the program did. The program is capture-ready: static shapes, no ``.item()``,
no branching on tensor values; the target-smoothing noise ε is drawn outside, from the agent's per-seed
generators, and passed in (the same random stream as the eager update).
"""

from __future__ import annotations

import types
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING

import torch
from torch import nn
from torch.func import functional_call

if TYPE_CHECKING:
    from .td3 import TD3Agent

ADAM_BETAS = (0.9, 0.999)
ADAM_EPS = 1e-8
"""torch.optim.Adam's defaults, which the eager update uses."""


def adam_state(optimizer: torch.optim.Optimizer, params: Sequence[nn.Parameter]) -> tuple[list, list, list]:
    """The (exp_avg, exp_avg_sq, step) tensors of ``optimizer`` for ``params``, created as Adam creates them
    (zeros, step 0) where the optimizer has not stepped yet."""
    averages, squares, steps = [], [], []
    for param in params:
        state = optimizer.state[param]
        if not state:
            state.update(step=torch.zeros((), dtype=torch.float32, device=param.device),
                         exp_avg=torch.zeros_like(param, memory_format=torch.preserve_format),
                         exp_avg_sq=torch.zeros_like(param, memory_format=torch.preserve_format))
        averages.append(state["exp_avg"])
        squares.append(state["exp_avg_sq"])
        steps.append(state["step"])
    return averages, squares, steps


def adam_(params: Sequence[torch.Tensor], grads: Sequence[torch.Tensor], averages: Sequence[torch.Tensor],
          squares: Sequence[torch.Tensor], steps: Sequence[torch.Tensor], lr: float) -> None:
    """One Adam step in place, torch.optim.Adam's rule (no weight decay, no amsgrad):
    t ← t + 1;  m ← β₁m + (1 − β₁)g;  v ← β₂v + (1 − β₂)g²;  θ ← θ − lr/(1 − β₁ᵗ) · m / (√v / √(1 − β₂ᵗ) + ε).

    torch.optim.Adam counts t per parameter; one optimizer's parameters step together, so their counts are
    equal and the two bias corrections are computed once, from all the counts (their maximum). Written per
    parameter, inductor fuses two scalar ``pow`` calls into every 16-wide iteration of every parameter's loop.
    A value that reads several buffers (more than ``torch._inductor.config.realize_reads_threshold``, 4) and is
    used by several loops is computed into a buffer of its own, which the loops then only read (the generated
    code has no ``pow`` left in them; Hopper, one thread: an ILC-SAN update 4.4 → 3.9-4.0 ms). Networks with
    fewer parameter tensors get the per-iteration ``pow`` back: slower, equal.
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


def value_and_grads(loss: Callable[..., torch.Tensor], *args, wrt: tuple[int, ...] = (0,)):
    """``torch.func.grad_and_value(loss, argnums=wrt)(*args)`` for arguments ``wrt`` that are lists of tensors:
    (the gradients, one list per argument in ``wrt``, or the one list; the loss, detached).

    Written with ``torch.autograd.grad`` on detached copies made leaves, which dynamo traces into one graph when
    ``torch._dynamo.config.trace_autograd_ops`` is on (:class:`DirectProgram` turns it on while it traces).
    ``grad_and_value`` also compiles, but with torch 2.13 an autograd Function that runs an opaque operator (the
    oneDNN products, :func:`ilcsan.snn.matmul.onednn_matmul_nt`) then gets a zero gradient for a weight whose
    layer input needs none (tested in ``tests/test_matmul.py``); traced this way its gradients are exact, so compiled
    runs can use every float32 path. A tensor the loss does not reach gets a zero gradient, as with ``torch.func``."""
    args = list(args)
    with torch.enable_grad():
        for index in wrt:
            args[index] = [tensor.detach().requires_grad_() for tensor in args[index]]
        value = loss(*args)
        leaves = [tensor for index in wrt for tensor in args[index]]
        flat = list(torch.autograd.grad(value, leaves, materialize_grads=True)) if leaves else []
    groups = []
    for index in wrt:
        groups.append(flat[:len(args[index])])
        flat = flat[len(args[index]):]
    return (tuple(groups) if len(wrt) > 1 else groups[0]), value.detach()


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
    """``module``'s parameters and buffers."""
    return [*module.parameters(), *module.buffers()]


class DirectProgram:
    """``function`` for one structure and set of shapes of its arguments: traced once by dynamo, compiled by
    inductor, then inductor's code called directly, without dynamo.

    Entering a dynamo-compiled function costs ~30-60 µs for a batch-1 action and ~250 µs for the update program
    (its bytecode fetches ~150 tensors from dicts and lists), even without guards. The compiled callable's inputs
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
        self.traced = torch.compile(with_own_code(function), fullgraph=True, dynamic=False, backend=self._compile,
                                    options={"guard_filter_fn": torch.compiler.skip_all_guards_unsafe})

    @property
    def direct(self) -> bool:
        return self.slots is not None

    def _compile(self, graph: torch.fx.GraphModule, example_inputs: list) -> Callable:
        """Inductor with its C++ wrapper, which calls the kernels from C++ instead of a Python function (measured
        on Hopper, one thread: an ILC-SAN update 6.16 → 5.88 ms, a batch-1 action 103 → 81 µs, for ~10 s more
        of first compilation)."""
        from torch._inductor.compile_fx import compile_fx

        self.compiled = compile_fx(graph, example_inputs, config_patches={"cpp_wrapper": True})
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
                result = self.traced(*args)
            if self.example_inputs is not None:
                self._bind(leaves, result)
            return result
        inputs = list(self.fixed)
        for slot, position in self.slots:
            inputs[slot] = leaves[position]
        outputs = self.compiled(*inputs)
        return tuple(outputs) if self.output_tuple else outputs[0]


class CompiledPerShape:
    """A module's forward through one :class:`DirectProgram` per shape and dtype of its inputs: acting (K, 1, N),
    evaluation (K, E, N) and Proxy Target's regression targets each get their own program. Call it under
    ``torch.no_grad()`` only."""

    def __init__(self, module: nn.Module):
        self.module, self.programs = module, {}

    def __call__(self, *inputs: torch.Tensor) -> torch.Tensor:
        inputs = tuple(x.contiguous() for x in inputs)  # a program assumes the layout it was compiled for
        key = tuple((x.shape, x.dtype) for x in inputs)
        program = self.programs.get(key)
        if program is None:
            program = self.programs[key] = DirectProgram(self.module.forward, module_tensors(self.module))
        return program(*inputs)


class UpdateProgram:
    """The two compiled variants of one TD3 update of ``agent`` (see the module docstring).

    ``run(batch, noise, delayed)`` performs one update in place and returns the summed losses as 0-dim
    tensors (critic, actor or None). With Proxy Target the agent fits its proxy before calling it; the
    program then reads the proxy as π' and leaves it alone.
    """

    def __init__(self, agent: TD3Agent, compile: bool = True):
        self.agent = agent
        self.actor_names = [name for name, _ in agent.actor.named_parameters()]
        self.critic_names = [name for name, _ in agent.critic.named_parameters()]
        self.target_actor_names = [name for name, _ in agent.actor_target.named_parameters()]
        self._parameters: dict[str, list[nn.Parameter]] | None = None
        self.soft_target_actor = agent.proxy is None  # Proxy Target: π' is the proxy, fitted, not averaged
        constants = [agent.scale, agent.offset]
        for module in (agent.actor, agent.critic, agent.actor_target, agent.critic_target, agent.exploration):
            constants += module_tensors(module) if module is not None else []
        self.critic_step = DirectProgram(self._critic_step, constants) if compile else self._critic_step
        self.delayed_step = DirectProgram(self._delayed_step, constants) if compile else self._delayed_step

    # ----------------------------------------------------------------------- the pure program

    def _critic_loss(self, critic: list, batch: dict, target: torch.Tensor) -> torch.Tensor:
        return self.agent.critic_loss(batch, target, as_function(self.agent.critic, critic, self.critic_names))

    def _actor_loss(self, actor: list, exploration: list, critic: list, batch: dict) -> torch.Tensor:
        agent = self.agent
        return agent.actor_loss(batch, as_function(agent.actor, actor, self.actor_names),
                                as_function(agent.critic, critic, self.critic_names),
                                exploration[0] if exploration else None)

    def _critic_step(self, tensors: dict, batch: dict, noise: torch.Tensor) -> torch.Tensor:
        agent = self.agent
        with torch.no_grad():
            target = agent.target_values(
                batch["next_obs"], noise, batch["reward"], batch["terminal"],
                as_function(agent.actor_target, tensors["actor_target"], self.target_actor_names),
                as_function(agent.critic_target, tensors["critic_target"], self.critic_names))
        grads, loss = value_and_grads(self._critic_loss, tensors["critic"], batch, target)
        adam_(tensors["critic"], grads, *tensors["critic_adam"], lr=agent.td3.critic_lr)
        return loss

    def _delayed_step(self, tensors: dict, batch: dict, noise: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        critic_loss = self._critic_step(tensors, batch, noise)
        lr = self.agent.config.learning_rate
        (grads, exploration_grads), actor_loss = value_and_grads(
            self._actor_loss, tensors["actor"], tensors["exploration"], tensors["critic"], batch, wrt=(0, 1))
        adam_(tensors["actor"], grads, *tensors["actor_adam"], lr=lr)
        if tensors["exploration"]:  # NoisySAN's σ_d, with the actor's learning rate
            adam_(tensors["exploration"], exploration_grads, *tensors["exploration_adam"], lr=lr)
        tau = self.agent.td3.tau
        if self.soft_target_actor:
            torch._foreach_lerp_(tensors["actor_target"], tensors["actor"], tau)
        torch._foreach_lerp_(tensors["critic_target"], tensors["critic"], tau)
        return critic_loss, actor_loss

    # ------------------------------------------------------------------------- the host side
    def tensors(self) -> dict[str, list]:
        """The agent's tensors the program reads and writes. The parameters keep their identity for the agent's
        life (checkpoints load into them in place), so their detached views are made once; the Adam state is
        looked up anew on each call, because loading a checkpoint replaces it."""
        agent = self.agent
        if self._parameters is None:
            modules = {"actor": agent.actor, "critic": agent.critic, "actor_target": agent.actor_target,
                       "critic_target": agent.critic_target, "exploration": agent.exploration}
            self._parameters = {key: list(module.parameters()) if module is not None else []
                                for key, module in modules.items()}
            self._views = {key: [p.detach() for p in params] for key, params in self._parameters.items()}
        tensors = {**self._views, "actor_adam": adam_state(agent.actor_optimizer, self._parameters["actor"]),
                   "critic_adam": adam_state(agent.critic_optimizer, self._parameters["critic"])}
        if agent.exploration is not None:
            tensors["exploration_adam"] = adam_state(agent.exploration.optimizer, self._parameters["exploration"])
        return tensors

    def run(self, batch: dict[str, torch.Tensor], noise: torch.Tensor,
            delayed: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
        """One update in place; returns (critic loss, actor loss or None) as 0-dim tensors."""
        tensors = self.tensors()
        batch = {name: value.contiguous() for name, value in batch.items()}  # the layout the program was built for
        with torch.no_grad():  # value_and_grads makes its own gradients; nothing outside is recorded
            if delayed:
                critic_loss, actor_loss = self.delayed_step(tensors, batch, noise)
                return critic_loss, actor_loss
            return self.critic_step(tensors, batch, noise), None
