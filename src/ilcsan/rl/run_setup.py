"""Setting up a training run: everything :class:`~ilcsan.rl.training.Trainer` trains with, built in the order that
lets a run that cannot start change nothing — the task first (a wrong name or a missing dependency is found before
a file is written), then the process settings, the evaluation environments, a memory check, the run folders (refused,
checked and locked), the matmul path (kept from the run's start when it resumes), the algorithm, replay buffer,
normaliser and generators, and finally the checkpoint (resumed) or the first episodes and config.json (a new run),
the provenance and the reporters.
"""

from __future__ import annotations

import sys

import numpy as np

from ..compute.process import apply_to_process
from ..runs import provenance
from ..runs.checkpoint import TrainingCheckpoints, open_for_training
from ..runs.directory import RunFileError
from .algorithms import build_algorithm
from .callbacks import Callbacks, ProgressReport, TensorBoardLog
from .matmul_choice import choose_matmul_path, describe_matmul_choice, recorded_matmul_path
from .normalizer import RunningNormalizer
from .ram import check_memory
from .replay import ReplayBuffer
from .tasks import make_envs


def set_up(run, resume: bool, progress: bool | None) -> None:
    """Build the parts of ``run`` (a :class:`~ilcsan.rl.training.Trainer` whose ``config``, ``directories`` and
    ``environments`` exist) onto it, in the module docstring's order. What holds a resource (the evaluation
    environments, the folder locks) is appended to the run's lists as it is made, so that the run's ``close`` frees
    whatever was built when a later step fails."""
    config, log = run.config, run.log
    contact_forces = config.task_contact_forces()
    apply_to_process(config.threads, config.matmul, config.device)
    for _ in config.seeds:
        run.eval_envs.append(make_envs(config.task, config.eval_episodes, contact_forces=contact_forces))
    environments = run.environments
    state_dim, action_dim = environments.state_dim, environments.action_dim
    check_memory(config, state_dim, action_dim)
    locks, resumable = open_for_training(run.directories, resume, log)
    run.locks.extend(locks)
    kept = kept_matmul_path(run) if resumable else None
    matmul_path, run.matmul_choice = kept or choose_matmul_path(config, state_dim, action_dim,
                                                                environments.episode_steps)
    log(describe_matmul_choice(run.matmul_choice))
    run.agent = build_algorithm(config, state_dim, action_dim, environments.action_scale, environments.action_offset,
                                environments.episode_steps, matmul_path)
    run.replay = ReplayBuffer(len(config.seeds), state_dim, action_dim, min(config.training.replay_size, config.steps))
    run.normalizer = RunningNormalizer(len(config.seeds), state_dim)
    run.rngs = [np.random.default_rng(seed) for seed in config.seeds]
    run.step, run.wall_seconds = 0, 0.0
    run.evaluations = [[] for _ in config.seeds]
    run.checkpoints = TrainingCheckpoints(run.directories, log)
    if resumable:
        run.checkpoints.restore(run, config, state_dim, action_dim)
    else:
        start(run)
    run.checkpoints.record_provenance(provenance.collect(run.step, config.matmul, run.matmul_choice["path"],
                                                         config.device))
    run.callbacks = Callbacks(TensorBoardLog([directory.tensorboard_folder() for directory in run.directories],
                                             run.step),
                              ProgressReport(sys.stderr.isatty() if progress is None else progress, log))


def kept_matmul_path(run):
    """The matmul path the run being resumed started on (:func:`recorded_matmul_path`), if it can be kept."""
    try:
        recorded = run.directories[0].matmul_choice()
    except RunFileError:
        return None
    return recorded_matmul_path(recorded, run.config.matmul)


def start(run) -> None:
    """Step 0 of a new run: the first episodes and each seed's config.json."""
    run.environments.start()
    run.normalizer.update(run.environments.observations)
    run.checkpoints.write_configs(run.config, {"matmul_path": run.matmul_choice})
