"""The off-policy algorithms that train an actor, by the name ``--algorithm`` takes (each declared, with its paper
and settings, in :mod:`ilcsan.methods`): TD3 (the paper's), DDPG and SAC, each one class behind the seam of
:class:`~ilcsan.rl.algorithms.base.OffPolicyAlgorithm`."""

from __future__ import annotations

from ... import methods
from ...config import RunConfig
from ..agent_settings import ComputeSettings, TaskSpace
from .base import OffPolicyAlgorithm
from .critic import Critics
from .sac import SAC
from .td3 import DDPG, TD3

__all__ = ["DDPG", "SAC", "TD3", "ComputeSettings", "Critics", "OffPolicyAlgorithm", "TaskSpace", "algorithm_class",
           "build_algorithm"]


def algorithm_class(name: str) -> type[OffPolicyAlgorithm]:
    """The class of ``--algorithm name`` (a name :func:`~ilcsan.config.check_settings` has accepted)."""
    return methods.declared("algorithm", name).training_class()


def build_algorithm(config: RunConfig, state_dim: int, action_dim: int, action_scale, action_offset,
                    episode_steps: int | None, matmul_path) -> OffPolicyAlgorithm:
    """The run's algorithm for its seeds, on its device, compiled or not as the run says."""
    task = TaskSpace(state_dim, action_dim, action_scale, action_offset, config.task, episode_steps)
    compute = ComputeSettings(config.device, config.compiles(), config.engine, matmul_path)
    return algorithm_class(config.algorithm)(config.actor, config.training, task, config.seeds, compute)
