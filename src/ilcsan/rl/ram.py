"""The RAM a run needs (networks, activations, replay buffers) and the machine's: checked before anything starts (one
clear line, not a crash)."""

from __future__ import annotations

import os

from ..config import RunConfig
from ..errors import UserError
from .algorithms import algorithm_class


def replay_bytes(state_dim: int, action_dim: int, capacity: int) -> int:
    """One seed's full replay buffer: capacity × (s, a, r, s', terminal) = capacity × (2N + M + 2) float32."""
    return capacity * (2 * state_dim + action_dim + 2) * 4


def memory_estimate(config: RunConfig, state_dim: int, action_dim: int) -> dict[str, int]:
    """A lower bound of the bytes a run needs: networks (weights, targets, gradients, Adam's two moments),
    one update's activations (measured: 5-14x the layers' outputs over T steps; 4x is counted) and the
    full replay buffers. Used to refuse, before anything starts, a run that cannot fit in memory."""
    actor, training, seeds = config.actor, config.training, len(config.seeds)
    algorithm = algorithm_class(config.algorithm)
    sizes = actor.layer_sizes(state_dim, algorithm.readouts * action_dim)
    if actor.network == "deep":
        timesteps, extra = 1, 0
    else:  # intra-layer weights and biases, decoder, encoder centres and widths
        timesteps = actor.timesteps
        extra = algorithm.readouts * action_dim * actor.population_out * (actor.population_out + 3) + 2 * sizes[0]
    critic = [state_dim + action_dim, *training.critic_hidden, 1]

    def parameters(widths: list[int]) -> int:
        return sum(a * b + b for a, b in zip(widths[:-1], widths[1:], strict=False))

    weights = 4 * seeds * 5 * (parameters(sizes) + extra + algorithm.critics * parameters(critic))
    activations = 4 * 4 * seeds * training.batch_size * timesteps * sum(sizes)
    replay = seeds * replay_bytes(state_dim, action_dim, min(training.replay_size, config.steps))
    return {"networks": weights + activations, "replay": replay}


def physical_memory() -> int | None:
    """Bytes of memory of this machine, or None where the OS does not say."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(config: RunConfig, state_dim: int, action_dim: int) -> None:
    """Refuse a run whose networks or replay buffers cannot fit in this machine's memory at all."""
    total = physical_memory()
    if not total:
        return
    need = memory_estimate(config, state_dim, action_dim)
    if config.device != "cpu":
        need["networks"] = 0  # on the accelerator; its memory is the framework's to report
    if sum(need.values()) > total:
        gib = 2 ** 30
        raise UserError(
            f"this run needs at least {need['networks'] / gib:.1f} GiB for its networks and "
            f"{need['replay'] / gib:.1f} GiB for its replay buffers, more than this machine's {total / gib:.1f} GiB; "
            "use fewer seeds per run, a smaller --batch-size, --hidden-width, --timesteps or populations")
