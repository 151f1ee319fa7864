"""Training runs: an off-policy algorithm around the actor — TD3 (Fujimoto et al. 2018), as the paper trains every
actor (Section III-E), or DDPG or SAC (:mod:`ilcsan.rl.algorithms`).

:meth:`Trainer.train` is their shared pseudocode: act (uniform random for ``start_steps``, then the algorithm's
exploring action), step the environments, store the transitions, update when due, evaluate when due.
K seeds train together in stacked weights, each with its own environment, replay rows, normaliser
statistics, random generators, checkpoint and metrics, laid out as K ordinary runs (``OUT`` for one seed,
``OUT/seed<k>`` for several; the folder's files are listed in :mod:`ilcsan.runs.directory`).

Around the loop, each in its own module:

- :class:`~ilcsan.rl.rollout.TrainingEnvironments`: the K environments and their running episodes;
- :func:`~ilcsan.rl.evaluation.run_lockstep`: the evaluation episodes;
- :mod:`~ilcsan.rl.run_setup`: building the run's parts, in an order that lets a run that cannot start change nothing;
- :func:`~ilcsan.runs.checkpoint.open_for_training`: the folders (refuse, check, lock, clean up);
- :class:`~ilcsan.runs.checkpoint.TrainingCheckpoints`: checkpoints, best policy, metrics, results, provenance, resume;
- :mod:`~ilcsan.rl.seed_state`: the layout of a seed's checkpoint, policy and result;
- :mod:`~ilcsan.rl.callbacks`: the progress bar, the evaluation lines and TensorBoard.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..compute.process import ProcessSettings
from ..config import RunConfig
from ..errors import TrainingDiverged
from ..runs.directory import RunDirectory, run_directories
from ..snn.diagnostics import EvaluationActions
from . import run_setup
from . import seed_state as per_seed
from .callbacks import Callbacks
from .evaluation import replay_diagnostics, run_lockstep, training_evaluation_seed
from .normalizer import RunningNormalizer
from .replay import ReplayBuffer
from .rollout import TrainingEnvironments, check_finite
from .validation import validate_run

LOSS_LIMIT = 1e12
"""A mean critic loss beyond this (or non-finite) means the run diverged."""


class Trainer:
    """The loop of one (possibly multi-seed) run and the parts it drives: environments, agent, replay
    buffer, normaliser and per-seed random generators."""

    def __init__(self, config: RunConfig, out: Path, resume: bool = False, progress: bool | None = None,
                 log=print):
        self.process_settings = ProcessSettings.now()  # given back at close()
        validate_run(config)
        self.config, self.log = config, log
        self.directories = [RunDirectory(path) for path in run_directories(Path(out), config.seeds)]
        self.locks: list = []
        self.callbacks = Callbacks()
        self.eval_envs: list = []
        # the task builds first: a run that cannot start changes nothing
        self.environments = TrainingEnvironments(config.task, config.seeds, config.task_contact_forces())
        try:
            run_setup.set_up(self, resume, progress)
        except BaseException:
            self.close()
            raise

    # ----------------------------------------------------------------------------- the loop
    def train(self) -> list[dict[str, Any]]:
        """Train until ``steps`` (an interrupted run continues from its checkpoint); returns each seed's
        result."""
        config = self.config
        losses: dict[str, float] = {}
        self._clock = TrainingClock(self.step)
        try:
            self.callbacks.start(self)
            while self.step < config.steps:
                losses = self.train_step() or losses
                if self.step % config.eval_every == 0 or self.step == config.steps:
                    self.wall_seconds += self._clock.stop()
                    speed = self._clock.speed(self.step)
                    self._after_evaluation(self.evaluate(), speed, losses)
                    self._clock.restart(self.step)
                elif self._checkpoint_due():
                    self.wall_seconds += self._clock.stop()
                    self._write_checkpoints()
                    self._clock.restart()
                self.callbacks.step(self)
        finally:
            self.close()
        return self.results()

    def _checkpoint_due(self) -> bool:
        """Whether ``checkpoint_minutes`` of training have passed since the last checkpoint (between evaluations)."""
        minutes = self.config.checkpoint_minutes
        return minutes > 0 and self._clock.since_checkpoint() >= 60.0 * minutes

    def train_step(self) -> dict[str, float] | None:
        """One environment step per seed: act, step, store, the updates when they are due (their mean losses are
        returned, else None), then what the training methods do every so many steps
        (:meth:`~ilcsan.rl.algorithms.base.OffPolicyAlgorithm.after_step`; the paper's methods do nothing there).

        What the parts called here do, which is all the step needs of them: ``environments.step`` steps each seed's
        environment once with its action and returns the transitions (s, a, r, s', terminal) and the seeds whose
        episode ended, which the loop resets; ``terminal`` is 1 only where the task terminated (a time limit's
        truncation ends an episode, but the target values still bootstrap from its s'). ``replay.add`` appends each
        seed's transition to that seed's rows, first in first out beyond ``min(replay_size, steps)`` rows.
        ``normalizer.update`` adds observations to each seed's running mean and variance: every s', and a new
        episode's first state, that seed's only."""
        training = self.config.training
        transition, finished = self.environments.step(self._explore(), step=self.step + 1)
        self.replay.add(*transition)
        self.normalizer.update(transition.next_obs)
        for index in finished:
            self.environments.reset(index, step=self.step + 1)
            self.agent.end_episode(index)
            self.normalizer.update(self.environments.observations, mask=np.arange(len(self.environments)) == index)
        self.step += 1
        losses = None
        if self.step >= training.update_after and self.step % training.update_every == 0:
            losses = self._learn()
        self.agent.after_step(self.step, self.replay, self.normalizer)  # the methods' work at intervals
        return losses

    def _explore(self) -> np.ndarray:
        """Uniform random actions during the first start_steps, then the algorithm's (TD3's: π(s) + N(0, σ²) clipped
        to the bounds, or its exploration method's, :mod:`ilcsan.rl.methods`; SAC's: a sample of its policy)."""
        if self.step < self.config.training.start_steps:
            scale, offset = self.environments.action_scale, self.environments.action_offset
            return np.stack([rng.uniform(offset - scale, offset + scale) for rng in self.rngs])
        return self.agent.explore(self.normalizer.normalize(self.environments.observations), self.rngs)

    def _act(self, observations: np.ndarray) -> np.ndarray:
        """The deterministic actions π(s) of the K seeds for their raw observations, (K, N) → (K, M) or
        (K, E, N) → (K, E, M) (an evaluation's E episodes)."""
        if observations.ndim == 2:
            return self._act(observations[:, None, :])[:, 0]
        return self.agent.act(self.normalizer.normalize(observations))

    def _learn(self) -> dict[str, float]:
        """update_every updates, each on a fresh minibatch per seed; returns the mean losses per seed."""
        training = self.config.training
        critic_total, actor_total, actor_count = 0.0, 0.0, 0
        self.agent.before_updates(self.evaluations)
        for _ in range(training.update_every):
            arrays = sample_minibatch(self.replay, self.normalizer, self.rngs, training)
            arrays.update(self.agent.extra_samples(self.replay, self.normalizer, self.rngs))
            losses = self.agent.update(self.agent.to_batch(arrays))
            critic_total = critic_total + losses["critic_loss"]
            if losses["actor_loss"] is not None:
                actor_total = actor_total + losses["actor_loss"]
                actor_count += 1
        critic_loss = float(critic_total) / training.update_every
        actor_loss = float(actor_total) / max(actor_count, 1)
        check_losses(critic_loss, actor_loss, self.step)
        seeds = len(self.environments)
        return {"critic_loss": critic_loss / seeds, "actor_loss": actor_loss / seeds}

    def evaluate(self) -> list[dict[str, float]]:
        """eval_episodes deterministic episodes per seed, all seeds in lockstep; the episode seeds are those of
        :func:`~ilcsan.rl.evaluation.training_evaluation_seed`."""
        seeds, step = self.config.seeds, self.step
        first_seeds = [training_evaluation_seed(seed, step // self.config.eval_every) for seed in seeds]

        def check(index: int, what: str, value) -> None:
            check_finite(value, what, seeds[index], step, "evaluation environment")

        actions = EvaluationActions(len(seeds), self.environments.action_scale, self.environments.action_offset)
        returns, lengths = run_lockstep(self.eval_envs, self._act, first_seeds, check, actions.observe)
        rows = [{"step": self.step, "eval_return_mean": float(np.mean(r)), "eval_return_std": float(np.std(r)),
                 "eval_length_mean": float(np.mean(n))} for r, n in zip(returns, lengths, strict=True)]
        measured = replay_diagnostics(self.agent, self.replay, self.normalizer, seeds, step)
        for row, action_row, diagnostics in zip(rows, actions.rows(), measured, strict=True):
            row.update(**action_row, **diagnostics)
        return rows

    # ----------------------------------------------------------------------- around the loop
    def _after_evaluation(self, rows: list[dict[str, float]], speed: float, losses: dict[str, float]) -> None:
        """Record each seed's evaluation, save its policy when it beats every earlier one, then checkpoint
        and report."""
        for index, row in enumerate(rows):
            row.update(wall_seconds=round(self.wall_seconds, 3), steps_per_second=round(speed, 2))
            improved = all(row["eval_return_mean"] > old["eval_return_mean"] for old in self.evaluations[index])
            self.evaluations[index].append(row)
            if improved:
                self.checkpoints.save_policy(index, {**self.policy_state(index),
                                                     "eval_return_mean": row["eval_return_mean"]}, self.step)
        self._write_checkpoints()
        self.callbacks.evaluated(self, rows, speed, losses)

    def _write_checkpoints(self) -> None:
        self.checkpoints.save(self)

    def results(self) -> list[dict[str, Any]]:
        """Each seed's folder, best evaluation (return and step), steps done and whether the run finished."""
        return [per_seed.seed_result(self.config, index, directory.path, self.evaluations[index], self.step,
                                     self.wall_seconds) for index, directory in enumerate(self.directories)]

    # --------------------------------------------------------------------------- checkpoints
    def seed_state(self, index: int, segments: list[str]) -> dict[str, Any]:
        """Seed ``index``'s checkpoint (:func:`~ilcsan.rl.seed_state.seed_state`)."""
        return per_seed.seed_state(self, index, segments)

    def load_seed_states(self, states: list[dict[str, Any]]) -> None:
        """Continue from the seeds' checkpoints (:func:`~ilcsan.rl.seed_state.load_seed_states`)."""
        per_seed.load_seed_states(self, states)

    def policy_state(self, index: int) -> dict[str, Any]:
        """Seed ``index``'s deployable policy (:func:`~ilcsan.rl.seed_state.policy_state`)."""
        return per_seed.policy_state(self, index)

    def close(self) -> None:
        """Close the reporters, environments and locks, and give the process the settings the run changed back
        (:class:`~ilcsan.compute.process.ProcessSettings`; safe to call twice)."""
        self.process_settings.restore()
        self.callbacks.close()
        for env in (env for row in self.eval_envs for env in row):
            env.close()
        self.environments.close()
        for lock in self.locks:
            lock.close()
        self.eval_envs, self.locks = [], []


class TrainingClock:
    """Training time, without evaluations and checkpoint writing: the run's ``wall_seconds``, the steps/s since the
    last evaluation, and the time since the last checkpoint."""

    def __init__(self, step: int):
        self.mark = self.checkpointed = time.perf_counter()
        self.interval_seconds, self.interval_start = 0.0, step

    def stop(self) -> float:
        """Seconds of training since the last (re)start, added to the interval's."""
        elapsed = time.perf_counter() - self.mark
        self.interval_seconds += elapsed
        return elapsed

    def speed(self, step: int) -> float:
        return (step - self.interval_start) / max(self.interval_seconds, 1e-9)

    def restart(self, step: int | None = None) -> None:
        """Count training time again after a checkpoint (an evaluation writes one too); with ``step``, a new
        interval (after an evaluation) starts there."""
        self.mark = self.checkpointed = time.perf_counter()
        if step is not None:
            self.interval_seconds, self.interval_start = 0.0, step

    def since_checkpoint(self) -> float:
        return time.perf_counter() - self.checkpointed


def sample_minibatch(replay: ReplayBuffer, normalizer: RunningNormalizer, rngs: list[np.random.Generator],
                     training) -> dict[str, np.ndarray]:
    """``batch_size`` transitions per seed, (K, B, ·), drawn uniformly with replacement from that seed's replay rows
    with its own generator; s and s' normalised with the seeds' current statistics (z-scores clipped to ±3), as the
    actor sees states when it acts."""
    arrays = replay.sample(rngs, training.batch_size)
    arrays["obs"] = normalizer.normalize(arrays["obs"])
    arrays["next_obs"] = normalizer.normalize(arrays["next_obs"])
    return arrays


def check_losses(critic_loss: float, actor_loss: float, step: int) -> None:
    """Stop a run whose summed losses are non-finite or beyond :data:`LOSS_LIMIT`."""
    if not (math.isfinite(critic_loss) and math.isfinite(actor_loss)) or abs(critic_loss) > LOSS_LIMIT:
        raise TrainingDiverged(
            f"step {step}: the training loss diverged (critic {critic_loss:.3g}, actor {actor_loss:.3g}); the run "
            "stopped and kept its last checkpoint — try a smaller learning rate")


def train(config: RunConfig, out: Path, resume: bool = False, progress: bool | None = None,
          log=print) -> list[dict[str, Any]]:
    """Train ``config`` into ``out`` (see the module docstring); returns each seed's result."""
    return Trainer(config, out, resume=resume, progress=progress, log=log).train()


def load_run_config(directory: Path) -> RunConfig:
    """The configuration of the run in ``directory`` (its config.json)."""
    return RunDirectory(directory).run_config()
