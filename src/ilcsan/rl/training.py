"""Training runs: TD3 around the actor, with evaluation, logging, checkpoints and resume.

The loop in :meth:`Trainer.train` reads like TD3's pseudocode; everything else (evaluation, logging,
checkpoints, progress) sits around it. K seeds train together in stacked weights, each with its own
environment, replay rows, normaliser statistics, random generators, checkpoint and metrics, laid out as
K ordinary runs (``OUT`` for one seed, ``OUT/seed<k>`` for several).

Run directory (one seed)::

    config.json      the run's configuration (enough to rebuild the actor)
    metrics.csv      one row per evaluation (step, eval_return_mean, eval_return_std, ...)
    result.json      best evaluation so far, steps done, finished flag
    policy.pt        the actor of the best evaluation with its frozen normaliser (deployable)
    checkpoint.pt    the full training state of the last evaluation (resume)
    replay/          the replay rows, one segment per checkpoint
    tensorboard/     TensorBoard event files
"""

from __future__ import annotations

import contextlib
import csv
import io
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..config import ENGINES, MATMUL_PRECISIONS, RunConfig
from ..errors import TrainingDiverged, UserError
from ..files import atomic_torch_save, atomic_write_json, atomic_write_text, read_json, safe_torch_load
from .memory import check_memory
from .normalizer import RunningNormalizer
from .replay import ReplayBuffer
from .tasks import action_bounds, capture_env_state, make_env, restore_env_state
from .td3 import TD3Agent

CHECKPOINT_FORMAT = "ilcsan-checkpoint"
POLICY_FORMAT = "ilcsan-policy"
FORMAT_VERSION = 1
METRIC_FIELDS = ("step", "eval_return_mean", "eval_return_std", "eval_length_mean", "wall_seconds",
                 "steps_per_second")
EVAL_SEED_OFFSET = 1_000_000
FLOAT32_MAX = float(np.finfo(np.float32).max)


def validate_run(config: RunConfig) -> None:
    """One clear sentence for every impossible run setting."""
    if config.steps < 1:
        raise UserError(f"--steps must be at least 1, got {config.steps}")
    if config.eval_every < 1 or config.eval_episodes < 1:
        raise UserError("--eval-every and --eval-episodes must be at least 1")
    if not config.seeds:
        raise UserError("give at least one seed")
    if len(set(config.seeds)) != len(config.seeds):
        raise UserError(f"seeds must be distinct, got {list(config.seeds)}")
    if config.engine not in ENGINES:
        raise UserError(f"--engine {config.engine!r} is not one of: {', '.join(ENGINES)}")
    if config.td3.batch_size < 1 or config.td3.update_every < 1 or config.td3.policy_delay < 1:
        raise UserError("--batch-size, --update-every and --policy-delay must be at least 1")
    try:
        device = torch.device(config.device)
    except (RuntimeError, TypeError, ValueError):
        raise UserError(f"--device {config.device!r} is not a device; use cpu, cuda or cuda:N") from None
    if device.type not in ("cpu", "cuda"):
        raise UserError(f"--device {config.device!r} is not supported; use cpu, cuda or cuda:N")
    if device.type == "cuda" and not torch.cuda.is_available():
        raise UserError("--device cuda was asked for but no CUDA device is available; use --device cpu")
    if device.type == "cuda" and (device.index or 0) >= torch.cuda.device_count():
        raise UserError(f"--device {config.device!r}: this machine has {torch.cuda.device_count()} CUDA device(s)")
    if config.compile not in ("auto", "on", "off"):
        raise UserError(f"--compile {config.compile!r} is not one of: auto, on, off")
    if config.matmul not in MATMUL_PRECISIONS:
        raise UserError(f"--matmul {config.matmul!r} is not one of: {', '.join(MATMUL_PRECISIONS)}")
    if config.threads is not None and config.threads < 1:
        raise UserError(f"--threads must be at least 1, got {config.threads}")
    most_threads = 4 * (os.cpu_count() or 1)
    if config.threads is not None and config.threads > most_threads:
        raise UserError(f"--threads {config.threads} is more than 4 per core ({most_threads} here); use at most "
                        f"{os.cpu_count() or 1}")


COMPILE_AUTO_STEPS = 50_000



def set_matmul_precision(name: str) -> None:
    """Apply ``--matmul`` to this process (torch's setting is global)."""
    torch.set_float32_matmul_precision(MATMUL_PRECISIONS[name])


def use_compile(config: RunConfig) -> bool:
    """Compile when asked, or (auto) when the run is long enough to repay ~10-30 s of compiling.

    Only spiking-actor agents are compiled, and only the actor and the no-grad target values (TD3Agent decides:
    DAN and the trained critic run faster eager)."""
    if config.compile == "auto":
        return config.steps >= COMPILE_AUTO_STEPS and config.engine == "fast"
    return config.compile == "on"


def run_directories(out: Path, seeds: tuple[int, ...]) -> list[Path]:
    """``OUT`` for one seed, ``OUT/seed<k>`` for several."""
    out = Path(out)
    return [out] if len(seeds) == 1 else [out / f"seed{seed}" for seed in seeds]


def _check_writable(directory: Path) -> None:
    try:
        directory.mkdir(parents=True, exist_ok=True)
        probe = directory / ".ilcsan-write-test"
        probe.write_bytes(b"0" * 65536)
        probe.unlink()
    except (OSError, ValueError) as error:  # ValueError: a path with a NUL byte
        message = getattr(error, "strerror", None) or error
        raise UserError(f"cannot write results to {directory}: {message}; choose another --out") from None


PENDING_CHECKPOINT = "checkpoint.next.pt"
"""A seed's new checkpoint before every seed of the run has one (two-phase commit of multi-seed runs)."""


def _lock_directory(directory: Path):
    """Hold an exclusive lock on ``directory/.lock`` while training; a second process is refused. The
    kernel drops the lock when the process dies, even by SIGKILL."""
    try:
        import fcntl
    except ImportError:  # Windows: no lock
        return None
    stream = open(directory / ".lock", "a+")  # noqa: SIM115 - held for the trainer's lifetime
    try:
        fcntl.flock(stream.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        stream.close()
        raise UserError(f"another ilcsan process is training in {directory}; wait for it to finish or stop it "
                        "first (two processes writing one run would corrupt it)") from None
    return stream


def _remove_temporary_files(directory: Path) -> None:
    """Delete the half-written temporary files an interrupted atomic write left (we hold the lock)."""
    for folder in (directory, directory / "replay"):
        if folder.is_dir():
            for path in folder.glob(".*.tmp"):
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()


def _finish_commit(directories: list[Path]) -> None:
    """Complete or undo a multi-seed checkpoint that a crash interrupted (see ``_write_checkpoints``).

    Phase 1 writes every seed's ``checkpoint.next.pt``; phase 2 renames them to ``checkpoint.pt``. If a
    seed still has only its old checkpoint while others have a pending one, phase 1 did not finish: the
    pending files are dropped. Otherwise (every seed either pending or already renamed) phase 2 is
    completed. So all seeds always resume from the same step."""
    pending = [d for d in directories if (d / PENDING_CHECKPOINT).exists()]
    if not pending:
        return
    step = safe_torch_load(pending[0] / PENDING_CHECKPOINT).get("step")
    complete = all(d in pending or ((d / "checkpoint.pt").exists() and
                                    safe_torch_load(d / "checkpoint.pt").get("step") == step)
                   for d in directories)
    for directory in pending:
        if complete:
            os.replace(directory / PENDING_CHECKPOINT, directory / "checkpoint.pt")
        else:
            os.remove(directory / PENDING_CHECKPOINT)


# ------------------------------------------------------------------------------ ensemble slicing
def _slice_params(module: torch.nn.Module, index: int, factor: int) -> dict[str, torch.Tensor]:
    return {name: p.detach()[factor * index: factor * (index + 1)].cpu().clone()
            for name, p in module.named_parameters()}


def _load_params(module: torch.nn.Module, slices: list[dict[str, torch.Tensor]], factor: int,
                 what: str) -> None:
    with torch.no_grad():
        for name, param in module.named_parameters():
            parts = []
            for per_seed in slices:
                if name not in per_seed:
                    raise UserError(f"the {what} in the checkpoint has no {name!r}: it belongs to another actor")
                parts.append(per_seed[name])
            stacked = torch.cat(parts).to(param.device, param.dtype)
            if stacked.shape != param.shape:
                raise UserError(f"the checkpoint's {what} {name!r} has shape {tuple(stacked.shape)}, this run "
                                f"needs {tuple(param.shape)}: it belongs to another actor or task")
            param.copy_(stacked)


def _slice_optimizer(optimizer: torch.optim.Optimizer, module: torch.nn.Module, index: int,
                     factor: int) -> dict[str, dict[str, torch.Tensor]]:
    state = {}
    for name, param in module.named_parameters():
        entry = optimizer.state.get(param)
        if not entry:
            continue
        state[name] = {key: (value.detach().cpu().clone() if value.dim() == 0
                             else value.detach()[factor * index: factor * (index + 1)].cpu().clone())
                       for key, value in entry.items()}
    return state


def _load_optimizer(optimizer: torch.optim.Optimizer, module: torch.nn.Module,
                    slices: list[dict[str, dict[str, torch.Tensor]]]) -> None:
    for name, param in module.named_parameters():
        if not all(name in per_seed for per_seed in slices):
            continue
        entry = {}
        for key, value in slices[0][name].items():
            if value.dim() == 0:
                entry[key] = value.clone()
            else:
                entry[key] = torch.cat([per_seed[name][key] for per_seed in slices]).to(param.device)
                if entry[key].shape != param.shape:
                    raise UserError(f"the checkpoint's optimizer state {name!r} has shape {tuple(entry[key].shape)}, "
                                    f"this run needs {tuple(param.shape)}: it belongs to another actor or task")
        optimizer.state[param] = entry


# ------------------------------------------------------------------------------------- trainer
class Trainer:
    """Owns the environments, agent, buffers and bookkeeping of one (possibly multi-seed) run."""

    def __init__(self, config: RunConfig, out: Path, resume: bool = False, progress: bool | None = None,
                 log=print):
        validate_run(config)
        self.config, self.log = config, log
        self.progress = sys.stderr.isatty() if progress is None else progress
        self.directories = run_directories(Path(out), config.seeds)
        if config.threads is not None:
            torch.set_num_threads(config.threads)
        set_matmul_precision(config.matmul)
        self._locks: list = []
        self.envs, self.eval_envs, self.writers = [], [], None
        try:
            self._prepare_directories(resume)
            self._setup(config)
        except BaseException:
            self.close()
            raise

    def _setup(self, config: RunConfig) -> None:
        seeds = config.seeds
        self.envs = [make_env(config.task, seed) for seed in seeds]
        self.eval_envs = [make_env(config.task) for _ in seeds]
        env = self.envs[0]
        self.state_dim = int(env.observation_space.shape[0])
        self.action_dim = int(env.action_space.shape[0])
        self.action_scale, self.action_offset = action_bounds(env)
        check_memory(config, self.state_dim, self.action_dim)
        self.agent = TD3Agent(config.actor, config.td3, self.state_dim, self.action_dim, self.action_scale,
                              self.action_offset, seeds, config.device, compile=use_compile(config))
        self.agent.actor.engine = config.engine
        self.agent.actor_target.engine = config.engine
        capacity = min(config.td3.replay_size, config.steps)
        self.replay = ReplayBuffer(len(seeds), self.state_dim, self.action_dim, capacity)
        self.normalizer = RunningNormalizer(len(seeds), self.state_dim)
        self.rngs = [np.random.default_rng(seed) for seed in seeds]
        self.step = 0
        self.wall_seconds = 0.0
        self.evaluations: list[list[dict[str, float]]] = [[] for _ in seeds]
        self.segments: list[list[str]] = [[] for _ in seeds]
        self.checkpointed_total = 0
        self.observations = np.zeros((len(seeds), self.state_dim))
        self.writers = None
        if self.resumable:
            self._load_checkpoints()
        else:
            self._start_episodes()
            for directory, seed in zip(self.directories, seeds, strict=True):
                atomic_write_json(directory / "config.json", config.for_seed(seed))
        self._open_writers()

    # ----------------------------------------------------------------------------- setup
    def _prepare_directories(self, resume: bool) -> None:
        existing = [d for d in self.directories if any((d / name).exists() for name in
                                                       ("checkpoint.pt", PENDING_CHECKPOINT, "metrics.csv"))]
        if existing and not resume:
            raise UserError(f"{existing[0]} already holds a run; add --resume to continue it, or choose "
                            "another --out")
        for directory in self.directories:
            _check_writable(directory)
        for directory in self.directories:
            self._locks.append(_lock_directory(directory))
        for directory in self.directories:
            _remove_temporary_files(directory)
        if resume:
            _finish_commit(self.directories)
        with_checkpoint = [d for d in self.directories if (d / "checkpoint.pt").exists()]
        if with_checkpoint and len(with_checkpoint) != len(self.directories):
            raise UserError("only some seeds of this run have a checkpoint; resume them one by one or "
                            "remove the incomplete seed folders")
        self.resumable = resume and bool(with_checkpoint)
        if resume and not with_checkpoint:
            self.log(f"no checkpoint in {self.directories[0]} yet; starting from step 0")

    def _open_writers(self) -> None:
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError:  # tensorboard is a dependency, but keep training without it
            return
        self.writers = [SummaryWriter(str(d / "tensorboard"), purge_step=self.step or None)
                        for d in self.directories]

    def _reset_env(self, index: int) -> None:
        observation, _ = self.envs[index].reset()
        self._check_finite(observation, "observation", index, step=self.step + 1)
        self.observations[index] = observation
        self.normalizer.update(self.observations, mask=np.arange(len(self.envs)) == index)

    def _start_episodes(self) -> None:
        for index, (env, seed) in enumerate(zip(self.envs, self.config.seeds, strict=True)):
            observation, _ = env.reset(seed=seed)
            self._check_finite(observation, "observation", index)
            self.observations[index] = observation
        self.normalizer.update(self.observations)
        self.episode_returns = np.zeros(len(self.envs))

    def _check_finite(self, value, what: str, index: int, where: str = "environment",
                      step: int | None = None) -> None:
        """Stop at once on NaN/inf (or beyond float32's range: the replay buffer stores float32), naming the
        step: the environment step being taken (1-based) while training, the evaluation's step otherwise."""
        if not np.all(np.abs(np.asarray(value, dtype=np.float64)) <= FLOAT32_MAX):
            raise TrainingDiverged(
                f"step {self.step if step is None else step}: the {where} returned a non-finite {what} for seed "
                f"{self.config.seeds[index]} (NaN, inf or beyond float32's range); the run stopped and kept "
                "its last checkpoint")

    # -------------------------------------------------------------------------------- acting
    def _explore(self) -> np.ndarray:
        """Uniform random actions during the first start_steps, then π(s) + N(0, σ²), clipped."""
        low, high = self.action_offset - self.action_scale, self.action_offset + self.action_scale
        if self.step < self.config.td3.start_steps:
            return np.stack([rng.uniform(low, high) for rng in self.rngs])
        action = self.agent.act(self.normalizer.normalize(self.observations[:, None, :])[:, 0])
        noise = np.stack([rng.standard_normal(self.action_dim) for rng in self.rngs])
        action = action + noise * self.config.td3.exploration_noise * self.action_scale
        return np.clip(action, low, high)

    def _env_step(self, actions: np.ndarray) -> None:
        """Step every seed's environment once and store the transitions."""
        count = len(self.envs)
        next_observations = np.zeros_like(self.observations)
        rewards, terminals = np.zeros(count), np.zeros(count)
        done = np.zeros(count, dtype=bool)
        for index, env in enumerate(self.envs):
            observation, reward, terminated, truncated, _ = env.step(actions[index])
            self._check_finite(observation, "observation", index, step=self.step + 1)
            self._check_finite(reward, "reward", index, step=self.step + 1)
            next_observations[index], rewards[index] = observation, reward
            terminals[index] = float(terminated)  # a time-limit truncation is not terminal
            done[index] = terminated or truncated
        self.replay.add(self.observations, actions, rewards, next_observations, terminals)
        self.observations = next_observations
        self.normalizer.update(self.observations)
        self.episode_returns = self.episode_returns + rewards
        for index in np.flatnonzero(done):
            self.episode_returns[index] = 0.0
            self._reset_env(int(index))

    # ------------------------------------------------------------------------------ learning
    def _learn(self) -> dict[str, float]:
        """update_every TD3 updates, each on a fresh minibatch per seed."""
        td3 = self.config.td3
        critic_total, actor_total, actor_count = 0.0, 0.0, 0
        for _ in range(td3.update_every):
            arrays = self.replay.sample(self.rngs, td3.batch_size)
            arrays["obs"] = self.normalizer.normalize(arrays["obs"])
            arrays["next_obs"] = self.normalizer.normalize(arrays["next_obs"])
            losses = self.agent.update(self.agent.to_batch(arrays))
            critic_total = critic_total + losses["critic_loss"]
            if losses["actor_loss"] is not None:
                actor_total = actor_total + losses["actor_loss"]
                actor_count += 1
        critic_loss = float(critic_total) / td3.update_every
        actor_loss = float(actor_total) / max(actor_count, 1)
        if not (math.isfinite(critic_loss) and math.isfinite(actor_loss)) or abs(critic_loss) > 1e12:
            raise TrainingDiverged(
                f"step {self.step}: the TD3 loss diverged (critic {critic_loss:.3g}, actor {actor_loss:.3g}); "
                "the run stopped and kept its last checkpoint — try a smaller learning rate")
        return {"critic_loss": critic_loss / len(self.envs), "actor_loss": actor_loss / len(self.envs)}

    # ---------------------------------------------------------------------------- evaluation
    def evaluate(self) -> list[dict[str, float]]:
        """eval_episodes deterministic episodes per seed (all seeds in lockstep, batch 1 each)."""
        config = self.config
        count = len(self.eval_envs)
        evaluation_index = self.step // config.eval_every
        returns = [[] for _ in range(count)]
        lengths = [[] for _ in range(count)]
        observations = np.zeros((count, self.state_dim))
        running, episode_return, episode_length = np.ones(count, bool), np.zeros(count), np.zeros(count, int)

        def reset(index: int) -> None:
            episode = len(returns[index])
            seed = EVAL_SEED_OFFSET + config.seeds[index] * 10_007 + evaluation_index * 101 + episode
            observations[index] = self.eval_envs[index].reset(seed=seed)[0]
            self._check_finite(observations[index], "observation", index, "evaluation environment")
            episode_return[index], episode_length[index] = 0.0, 0

        for index in range(count):
            reset(index)
        while running.any():
            actions = self.agent.act(self.normalizer.normalize(observations[:, None, :])[:, 0])
            for index in np.flatnonzero(running):
                observation, reward, terminated, truncated, _ = self.eval_envs[index].step(actions[index])
                self._check_finite(observation, "observation", index, "evaluation environment")
                self._check_finite(reward, "reward", index, "evaluation environment")
                observations[index] = observation
                episode_return[index] += reward
                episode_length[index] += 1
                if terminated or truncated:
                    returns[index].append(float(episode_return[index]))
                    lengths[index].append(int(episode_length[index]))
                    if len(returns[index]) >= config.eval_episodes:
                        running[index] = False
                    else:
                        reset(int(index))
        return [{"step": self.step, "eval_return_mean": float(np.mean(r)), "eval_return_std": float(np.std(r)),
                 "eval_length_mean": float(np.mean(n))} for r, n in zip(returns, lengths, strict=True)]

    # ----------------------------------------------------------------------------- the loop
    def train_step(self) -> dict[str, float] | None:
        """One environment step per seed, and TD3's updates when they are due (TD3's pseudocode)."""
        td3 = self.config.td3
        self._env_step(self._explore())
        self.step += 1
        if self.step >= td3.update_after and self.step % td3.update_every == 0:
            return self._learn()
        return None

    def train(self) -> list[dict[str, Any]]:
        """Run TD3 until ``steps``; returns each seed's result. Interrupted runs resume from here."""
        config = self.config
        from tqdm import tqdm

        bar = tqdm(total=config.steps, initial=self.step, disable=not self.progress, unit="step",
                   dynamic_ncols=True, desc=f"{config.task} {config.actor.preset}")
        last_time, last_step = time.perf_counter(), self.step
        losses: dict[str, float] = {}
        try:
            while self.step < config.steps:
                losses = self.train_step() or losses
                if self.step % config.eval_every == 0 or self.step == config.steps:
                    now = time.perf_counter()
                    self.wall_seconds += now - last_time
                    speed = (self.step - last_step) / max(now - last_time, 1e-9)
                    self._after_evaluation(self.evaluate(), speed, losses)
                    last_time, last_step = time.perf_counter(), self.step
                bar.update(1)
                if self.step % 200 == 0 and self.progress:
                    bar.set_postfix_str(self._status())
        finally:
            bar.close()
            self.close()
        return self.results()

    def _status(self) -> str:
        bests = [max((row["eval_return_mean"] for row in rows), default=float("nan")) for rows in self.evaluations]
        return f"best {np.nanmean(bests):.1f}" if self.evaluations[0] else "no evaluation yet"

    def _after_evaluation(self, rows: list[dict[str, float]], speed: float, losses: dict[str, float]) -> None:
        for index, row in enumerate(rows):
            row.update(wall_seconds=round(self.wall_seconds, 3), steps_per_second=round(speed, 2))
            improved = all(row["eval_return_mean"] > old["eval_return_mean"] for old in self.evaluations[index])
            self.evaluations[index].append(row)
            if improved:
                self._write_policy(index, row)
            if self.writers:
                writer = self.writers[index]
                writer.add_scalar("eval/return_mean", row["eval_return_mean"], self.step)
                writer.add_scalar("eval/return_std", row["eval_return_std"], self.step)
                writer.add_scalar("train/steps_per_second", speed, self.step)
                for name, value in losses.items():
                    writer.add_scalar(f"train/{name}", value, self.step)
                writer.flush()
        self._write_checkpoints()
        returns = " ".join(f"{row['eval_return_mean']:.1f}" for row in rows)
        message = (f"[{self.config.task} {self.config.label or self.config.actor.preset}] step {self.step}: "
                   f"eval return {returns} · best {self._status().removeprefix('best ')} · {speed:.0f} steps/s")
        if self.progress:
            from tqdm import tqdm

            tqdm.write(message)
        else:
            self.log(message)

    def results(self) -> list[dict[str, Any]]:
        output = []
        for directory, seed, rows in zip(self.directories, self.config.seeds, self.evaluations, strict=True):
            best = max(rows, key=lambda row: row["eval_return_mean"]) if rows else None
            output.append({"seed": seed, "directory": str(directory),
                           "best_return": best["eval_return_mean"] if best else None,
                           "best_step": best["step"] if best else None, "steps_done": self.step,
                           "steps_total": self.config.steps, "finished": self.step >= self.config.steps,
                           "wall_seconds": round(self.wall_seconds, 3)})
        return output

    def close(self) -> None:
        if self.writers:
            for writer in self.writers:
                writer.close()
            self.writers = None
        for env in self.envs + self.eval_envs:
            env.close()
        for lock in self._locks:
            if lock is not None:
                lock.close()
        self._locks = []

    @contextlib.contextmanager
    def _disk_errors(self, directory: Path):
        """A full or failing disk while writing results: one clear line; the last checkpoint is kept."""
        try:
            yield
        except OSError as error:
            raise UserError(f"step {self.step}: cannot write to {directory}: {error.strerror or error}; the last "
                            "checkpoint is kept: free some space, then continue with --resume") from None

    # ---------------------------------------------------------------------------- checkpoints
    def policy_state(self, index: int) -> dict[str, Any]:
        """The deployable actor of seed ``index``: weights, config, frozen normaliser, action bounds."""
        return {
            "format": POLICY_FORMAT, "version": FORMAT_VERSION, "task": self.config.task,
            "actor_config": self.config.actor.to_dict(), "state_dim": self.state_dim,
            "action_dim": self.action_dim, "action_scale": torch.as_tensor(self.action_scale),
            "action_offset": torch.as_tensor(self.action_offset),
            "actor": _slice_params(self.agent.actor, index, 1),
            "obs_mean": torch.as_tensor(self.normalizer.mean[index]),
            "obs_std": torch.as_tensor(self.normalizer.std[index]), "obs_clip": float(self.normalizer.clip),
            "step": self.step, "seed": self.config.seeds[index],
        }

    def _write_policy(self, index: int, row: dict[str, float]) -> None:
        state = self.policy_state(index)
        state["eval_return_mean"] = row["eval_return_mean"]
        with self._disk_errors(self.directories[index]):
            atomic_torch_save(self.directories[index] / "policy.pt", state)

    def _write_metrics(self, index: int) -> None:
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=METRIC_FIELDS, extrasaction="ignore", lineterminator="\n")
        writer.writeheader()
        writer.writerows(self.evaluations[index])
        atomic_write_text(self.directories[index] / "metrics.csv", buffer.getvalue())

    def _write_checkpoints(self) -> None:
        """Segments, metrics, then checkpoint.pt, then result.json: a crash anywhere keeps the previous
        checkpoint, and result.json never says "finished" before the final checkpoint is in place.

        With several seeds every new checkpoint is first written as ``checkpoint.next.pt``, then all are
        renamed; a crash in between is completed or undone on resume (:func:`_finish_commit`), so the
        seeds of a run always resume from the same step."""
        target = PENDING_CHECKPOINT if len(self.directories) > 1 else "checkpoint.pt"
        for index, directory in enumerate(self.directories):
            with self._disk_errors(directory):
                segment = self.replay.write_segment(directory, index, self.checkpointed_total)
                if segment is not None:
                    self.segments[index].append(segment)
                self._write_metrics(index)
                atomic_torch_save(directory / target, self._checkpoint_state(index))
        if target == PENDING_CHECKPOINT:
            for directory in self.directories:
                os.replace(directory / PENDING_CHECKPOINT, directory / "checkpoint.pt")
        self._write_results()
        for index, directory in enumerate(self.directories):
            ReplayBuffer.prune_segments(directory, self.segments[index])
        self.checkpointed_total = self.replay.total

    def _write_results(self) -> None:
        for directory, result in zip(self.directories, self.results(), strict=True):
            with self._disk_errors(directory):
                atomic_write_json(directory / "result.json", {k: v for k, v in result.items() if k != "directory"})

    def _checkpoint_state(self, index: int) -> dict[str, Any]:
        agent = self.agent
        env_state = capture_env_state(self.envs[index])
        return {
            "format": CHECKPOINT_FORMAT, "version": FORMAT_VERSION,
            "config": self.config.for_seed(self.config.seeds[index]),
            "state_dim": self.state_dim, "action_dim": self.action_dim,
            "step": self.step, "updates": agent.updates, "wall_seconds": self.wall_seconds,
            "actor": _slice_params(agent.actor, index, 1),
            "actor_target": _slice_params(agent.actor_target, index, 1),
            "critic": _slice_params(agent.critic, index, 2),
            "critic_target": _slice_params(agent.critic_target, index, 2),
            "actor_optimizer": _slice_optimizer(agent.actor_optimizer, agent.actor, index, 1),
            "critic_optimizer": _slice_optimizer(agent.critic_optimizer, agent.critic, index, 2),
            "normalizer": {k: (torch.as_tensor(v) if isinstance(v, np.ndarray) else v)
                           for k, v in self.normalizer.state(index).items()},
            "replay": {"total": self.replay.total, "capacity": self.replay.capacity,
                       "segments": list(self.segments[index])},
            "rng": {"numpy": self.rngs[index].bit_generator.state,
                    "noise": agent.noise_generators[index].get_state()},
            "env": {"observation": torch.as_tensor(self.observations[index]),
                    "episode_return": float(self.episode_returns[index]),
                    "physics": None if env_state["physics"] is None else torch.as_tensor(env_state["physics"]),
                    "kind": env_state["kind"], "elapsed": env_state["elapsed"],
                    "np_random": env_state["np_random"]},
            "evaluations": self.evaluations[index],
        }

    def _load_checkpoints(self) -> None:
        try:
            self._restore_checkpoints()
        except UserError:
            raise
        except (KeyError, TypeError, ValueError, AttributeError, IndexError, RuntimeError) as error:
            raise UserError(f"the checkpoint in {self.directories[0] if len(self.directories) == 1 else 'a seed'} "
                            f"is incomplete or from another version of ilcsan ({type(error).__name__}: "
                            f"{str(error)[:120]}); start again without --resume, or choose another --out") from None

    def _restore_checkpoints(self) -> None:
        states = [safe_torch_load(d / "checkpoint.pt") for d in self.directories]
        for directory, state in zip(self.directories, states, strict=True):
            if state.get("format") != CHECKPOINT_FORMAT or state.get("version") != FORMAT_VERSION:
                raise UserError(f"{directory / 'checkpoint.pt'} is not an ilcsan training checkpoint (format "
                                f"{state.get('format')!r} v{state.get('version')})")
            saved = RunConfig.from_dict(state["config"])
            mismatch = [name for name in ("task", "actor", "td3", "steps", "eval_every", "eval_episodes")
                        if getattr(saved, name) != getattr(self.config, name)]
            if mismatch:
                raise UserError(f"{directory} was trained with different settings ({', '.join(mismatch)}); "
                                "resume with the same command, or choose another --out")
            if state["state_dim"] != self.state_dim or state["action_dim"] != self.action_dim:
                raise UserError(f"{directory}'s checkpoint was made for another task shape")
        steps = {state["step"] for state in states}
        if len(steps) != 1:
            raise UserError(f"the seeds' checkpoints are at different steps ({sorted(steps)}); resume them one "
                            "by one")
        agent = self.agent
        _load_params(agent.actor, [s["actor"] for s in states], 1, "actor")
        _load_params(agent.actor_target, [s["actor_target"] for s in states], 1, "target actor")
        _load_params(agent.critic, [s["critic"] for s in states], 2, "critic")
        _load_params(agent.critic_target, [s["critic_target"] for s in states], 2, "target critic")
        _load_optimizer(agent.actor_optimizer, agent.actor, [s["actor_optimizer"] for s in states])
        _load_optimizer(agent.critic_optimizer, agent.critic, [s["critic_optimizer"] for s in states])
        agent.updates = states[0]["updates"]
        self.step = states[0]["step"]
        self.wall_seconds = float(states[0]["wall_seconds"])
        self.episode_returns = np.zeros(len(states))
        for index, (directory, state) in enumerate(zip(self.directories, states, strict=True)):
            self.normalizer.load(index, {k: (v.numpy() if torch.is_tensor(v) else v)
                                         for k, v in state["normalizer"].items()})
            replay = state["replay"]
            self.segments[index] = list(replay["segments"])
            self.replay.load_segments(directory, index, self.segments[index], replay["total"])
            ReplayBuffer.prune_segments(directory, self.segments[index])
            self.rngs[index].bit_generator.state = state["rng"]["numpy"]
            agent.noise_generators[index].set_state(state["rng"]["noise"])
            self.evaluations[index] = list(state["evaluations"])
            self._write_metrics(index)
            self._restore_episode(index, state["env"])
        self._write_results()  # a crash may have come between the checkpoint and its result.json
        self.checkpointed_total = self.replay.total
        self.log(f"resumed {self.directories[0] if len(self.directories) == 1 else self.directories[0].parent} "
                 f"at step {self.step}")

    def _restore_episode(self, index: int, saved: dict[str, Any]) -> None:
        env = self.envs[index]
        env.reset(seed=self.config.seeds[index])
        snapshot = {"physics": None if saved["physics"] is None else saved["physics"].numpy(),
                    "kind": saved["kind"], "elapsed": saved["elapsed"], "np_random": saved["np_random"]}
        if restore_env_state(env, snapshot):
            self.observations[index] = saved["observation"].numpy()
            self.episode_returns[index] = saved["episode_return"]
        else:
            self.log(f"note: {self.config.task} cannot restore a running episode; seed "
                     f"{self.config.seeds[index]} resumes with a new episode (not bit-identical)")
            observation, _ = env.reset(seed=self.config.seeds[index] + self.step)
            self.observations[index] = observation


def train(config: RunConfig, out: Path, resume: bool = False, progress: bool | None = None,
          log=print) -> list[dict[str, Any]]:
    """Train ``config`` into ``out`` (see module docstring); returns each seed's result."""
    trainer = Trainer(config, out, resume=resume, progress=progress, log=log)
    return trainer.train()


def load_run_config(directory: Path) -> RunConfig:
    return RunConfig.from_dict(read_json(Path(directory) / "config.json", "run config"))


__all__ = ["RunConfig", "Trainer", "train", "validate_run", "run_directories", "load_run_config",
           "CHECKPOINT_FORMAT", "POLICY_FORMAT"]
