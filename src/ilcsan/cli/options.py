"""Command-line options shared by the commands: argument types, seed lists, the actor and run switches."""

from __future__ import annotations

import argparse
from typing import Any

from ..errors import UserError

# ------------------------------------------------------------------------------------ helpers
MAX_SEEDS = 1000


def parse_seeds(text: str) -> tuple[int, ...]:
    """'3' → (3,), '0-9' → (0..9), '0,2,5' → (0, 2, 5)."""
    seeds: list[int] = []
    try:
        for part in text.split(","):
            part = part.strip()
            if "-" in part[1:]:
                first, last = part.split("-", 1) if not part.startswith("-") else (part, part)
                low, high = int(first), int(last)
                if high < low:
                    raise ValueError
                if high - low >= MAX_SEEDS:
                    raise UserError(f"--seeds {text!r} gives {high - low + 1} seeds; one run trains at most "
                                    f"{MAX_SEEDS} together")
                seeds.extend(range(low, high + 1))
            else:
                seeds.append(int(part))
    except UserError:
        raise
    except ValueError:
        raise UserError(f"--seeds {text!r} is not a seed list; write e.g. 0, 0-9 or 0,2,5") from None
    if any(seed < 0 for seed in seeds) or len(set(seeds)) != len(seeds):
        raise UserError(f"--seeds {text!r}: seeds must be distinct non-negative integers")
    if len(seeds) > MAX_SEEDS:
        raise UserError(f"--seeds {text!r} gives {len(seeds)} seeds; one run trains at most {MAX_SEEDS} together")
    return tuple(seeds)


def _int_at_least(minimum: int):
    """An argparse type: a whole number (underscores allowed) of at least ``minimum``."""

    def parse(text: str) -> int:
        try:
            value = int(text.replace("_", ""))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{text!r} must be at least {minimum}")
        return value

    return parse


_positive_int = _int_at_least(1)
_non_negative_int = _int_at_least(0)


def _finite_float(text: str) -> float:
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} must be finite")
    return value


ACTOR_SWITCHES: list[tuple[str, dict[str, Any]]] = [
    ("--encoder", {"help": "input coding: pop-det (fully spiking) | pop-prob | pop | layer | two-neuron"}),
    ("--neuron", {"help": "backbone neuron: clif | dynamic (MDC-SAN)"}),
    ("--hidden-layers", {"type": _positive_int, "help": "number of hidden layers, 1-4 (paper: 2)"}),
    ("--hidden-width", {"type": _positive_int, "help": "neurons per hidden layer (paper: 256)"}),
    ("--intra", {"help": "intra-layer connections: intra | self | lateral | bias | lateral+bias | self+bias | "
                         "self+lateral | none"}),
    ("--decoder", {"help": "decoder statistic: last | max | mean (LI membrane voltage) | fr (firing rate)"}),
    ("--alpha-v-li", {"type": _finite_float, "help": "voltage decay of the decoder's LI neuron (paper: 1.0)"}),
    ("--timesteps", {"type": _positive_int, "help": "simulation time T per action (paper: 5)"}),
    ("--population-in", {"type": _positive_int, "help": "encoder neurons per state dimension (paper: 10)"}),
    ("--population-out", {"type": _positive_int, "help": "output neurons per action dimension (paper: 10)"}),
    ("--alpha-c", {"type": _finite_float, "help": "CLIF current decay (paper: 0.5)"}),
    ("--alpha-v", {"type": _finite_float, "help": "CLIF voltage decay (paper: 0.75)"}),
    ("--v-th", {"type": _finite_float, "help": "CLIF threshold (paper: 0.5)"}),
    ("--surrogate-width", {"type": _finite_float, "help": "rectangular surrogate window (paper: 0.5)"}),
    ("--actor-lr", {"type": _finite_float, "dest": "learning_rate",
                    "help": "actor learning rate (spiking 1e-4, DAN 1e-3)"}),
]
ACTOR_DESTS = ["encoder", "neuron", "hidden_layers", "hidden_width", "intra", "decoder", "alpha_v_li", "timesteps",
               "population_in", "population_out", "alpha_c", "alpha_v", "v_th", "surrogate_width", "learning_rate"]


def _add_actor_switches(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("actor (a preset, then any switch overrides it; see `ilcsan actors`)")
    group.add_argument("--actor", "--preset", dest="preset", default="ilc-san",
                       help="ilc-san (default) | popsan | mdc-san | akl | dan")
    for flag, options in ACTOR_SWITCHES:
        group.add_argument(flag, **options)


def _add_run_options(parser: argparse.ArgumentParser, steps_default: int | None) -> None:
    parser.add_argument("--seeds", "--seed", dest="seeds", default="0",
                        help="seed or seeds: 0, 0-9 or 0,2,5; several seeds train together in one process")
    parser.add_argument("--steps", type=_positive_int, default=steps_default,
                        help=f"environment steps per seed (default {steps_default})")
    parser.add_argument("--eval-every", type=_positive_int, default=None,
                        help="evaluate every this many steps (paper: 10000)")
    parser.add_argument("--eval-episodes", type=_positive_int, default=None,
                        help="episodes per evaluation (paper: 10)")
    parser.add_argument("--start-steps", type=_non_negative_int, default=None,
                        help="uniformly random actions before the actor acts (paper: 10000)")
    parser.add_argument("--update-after", type=_non_negative_int, default=None,
                        help="first TD3 update at this step (paper: 1000)")
    parser.add_argument("--update-every", type=_positive_int, default=None,
                        help="TD3 updates run in chunks of this many, one per step (authors' code: 50)")
    parser.add_argument("--batch-size", type=_positive_int, default=None, help="minibatch size (paper: 100)")
    parser.add_argument("--device", default="cpu", help="cpu (default) | cuda | cuda:N")
    parser.add_argument("--engine", default="fast", help="fast (layer-major, default) | reference (Algorithm 1)")
    parser.add_argument("--threads", type=_positive_int, default=None,
                        help="torch threads (default: torch's own; use 1 when several runs share the cores)")
    parser.add_argument("--compile", default="auto",
                        help="torch.compile the spiking actor and the no-grad target values (the trained critic and "
                             "DAN run eager, faster): auto (default: on for runs of 50000 steps or more) | on | off")
    parser.add_argument("--matmul", default="float32",
                        help="float32 (default) | bf16: matmul inputs rounded to bfloat16 with float32 accumulation, "
                             "on AMX/AVX512-BF16 CPUs (and TF32/bf16 on CUDA); pays on large matmuls (Ant, many seeds)")


def build_run_config(args: argparse.Namespace, task: str | None = None):
    """A :class:`~ilcsan.training.RunConfig` from parsed ``train`` arguments."""
    from ..config import RunConfig, TD3Config, actor_config

    overrides = {dest: getattr(args, dest, None) for dest in ACTOR_DESTS}
    actor = actor_config(args.preset, **overrides)
    td3_overrides = {name: getattr(args, name) for name in ("start_steps", "update_after", "update_every",
                                                             "batch_size") if getattr(args, name, None) is not None}
    defaults = {"eval_every": 10_000, "eval_episodes": 10}
    return RunConfig(
        task=task or args.task, seeds=parse_seeds(args.seeds), steps=args.steps,
        eval_every=args.eval_every or defaults["eval_every"],
        eval_episodes=args.eval_episodes or defaults["eval_episodes"],
        actor=actor, td3=TD3Config(**td3_overrides), device=args.device, engine=args.engine, threads=args.threads,
        compile=args.compile, matmul=args.matmul, label=getattr(args, "label", None),
    )

