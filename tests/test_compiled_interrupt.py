"""Ctrl-C while a compiled program runs: a KeyboardInterrupt, whatever the program was doing.

A compiled program (inductor's C++ wrapper) calls Python-implemented operators, such as the oneDNN products
(:func:`ilcsan.compute.matmul.onednn_matmul_nt`), through the dispatcher's C interface. A KeyboardInterrupt raised
inside such an operator reaches the caller only as "API call failed", a RuntimeError: training would end with a
traceback instead of its "interrupted; continue with --resume" line (seen when stopping a run on that path).
"""

from __future__ import annotations

import os
import signal

import pytest
import torch

from ilcsan.compute.programs import OPERATOR_NAMESPACE, DirectProgram

calls = {"armed": False, "count": 0}


@torch.library.custom_op(f"{OPERATOR_NAMESPACE}::test_doubled_with_ctrl_c", mutates_args=())
def doubled_with_ctrl_c(x: torch.Tensor) -> torch.Tensor:
    """2x, after sending this process SIGINT when armed: a Ctrl-C that lands inside a Python operator."""
    calls["count"] += 1
    if calls["armed"]:
        os.kill(os.getpid(), signal.SIGINT)
    return 2 * x


@doubled_with_ctrl_c.register_fake
def _(x: torch.Tensor) -> torch.Tensor:
    return torch.empty_like(x)


def plus_one_doubled(x: torch.Tensor) -> torch.Tensor:
    return doubled_with_ctrl_c(x) + 1  # as ilcsan calls its operators: the graph holds their overload


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="needs POSIX signal masks")
def test_ctrl_c_inside_a_python_operator_of_a_compiled_program_is_a_keyboard_interrupt():
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        program = DirectProgram(plus_one_doubled)
        x = torch.arange(3.0)
        with torch.no_grad():
            assert program(x).tolist() == [1.0, 3.0, 5.0]  # traced, compiled, run: unarmed
            assert program.direct and program.holds_signals and calls["count"] >= 1
            calls["armed"] = True
            before = calls["count"]
            with pytest.raises(KeyboardInterrupt):
                program(x)
            assert calls["count"] == before + 1, "the operator ran once, the interrupt came after it"
            calls["armed"] = False
            assert program(x).tolist() == [1.0, 3.0, 5.0], "the program still runs after the interrupt"
    finally:
        calls["armed"] = False
        signal.signal(signal.SIGINT, previous)
