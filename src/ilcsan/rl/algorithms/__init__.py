"""The off-policy algorithms that train an actor, by the name ``--algorithm`` takes (:data:`ilcsan.config.
ALGORITHM_PAPERS` says where each comes from): TD3 (the paper's), DDPG and SAC, each one class behind the seam of
:class:`~ilcsan.rl.algorithms.base.OffPolicyAlgorithm`."""

from __future__ import annotations

from ...config import ALGORITHM_PAPERS, RunConfig
from .base import OffPolicyAlgorithm
from .critic import Critics
from .sac import SAC
from .td3 import DDPG, TD3

__all__ = ["ALGORITHMS", "DDPG", "SAC", "TD3", "Critics", "OffPolicyAlgorithm", "algorithm_class", "build_algorithm"]

ALGORITHMS: dict[str, type[OffPolicyAlgorithm]] = {"td3": TD3, "ddpg": DDPG, "sac": SAC}
assert set(ALGORITHMS) == set(ALGORITHM_PAPERS), "every algorithm has its paper, every paper its algorithm"


def algorithm_class(name: str) -> type[OffPolicyAlgorithm]:
    """The class of ``--algorithm name`` (a name :func:`~ilcsan.config.check_settings` has accepted)."""
    return ALGORITHMS[name]


def build_algorithm(config: RunConfig, state_dim: int, action_dim: int, action_scale, action_offset,
                    episode_steps: int | None, matmul) -> OffPolicyAlgorithm:
    """The run's algorithm for its seeds, on its device, compiled or not as the run says."""
    return algorithm_class(config.algorithm)(
        config.actor, config.td3, state_dim, action_dim, action_scale, action_offset, config.seeds, config.device,
        compile=config.compiles(), engine=config.engine, task=config.task, episode_steps=episode_steps,
        matmul=matmul)
