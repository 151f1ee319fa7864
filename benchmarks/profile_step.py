"""Where one training step's time goes once the update runs as one compiled program: prints one Markdown table.

One seed of a preset on a task, one torch thread, after a warm-up in which everything compiles. The step is timed
in its parts (acting, environment, replay sampling, the update), and the update is split into its matrix
products (the step's recorded products replayed alone on the run's matmul path, as ``speed.py``'s floor: the
compiled program calls them from C++, out of the profiler's sight) and everything else the program runs (the
fused neuron, loss and Adam kernels and the program's own calls). Run it on an idle machine:

    .venv/bin/python benchmarks/profile_step.py --task Hopper --preset ilc-san
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from speed import matmul_floor  # noqa: E402

from ilcsan.config import RunConfig, TrainingConfig, actor_config  # noqa: E402
from ilcsan.rl.training import Trainer, sample_minibatch  # noqa: E402


def mean_us(function, calls: int) -> float:
    start = time.perf_counter()
    for _ in range(calls):
        function()
    return (time.perf_counter() - start) / calls * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="Hopper")
    parser.add_argument("--preset", default="ilc-san")
    parser.add_argument("--matmul", default="float32", choices=("float32", "bf16"))
    parser.add_argument("--updates", type=int, default=200, help="timed updates")
    args = parser.parse_args()
    config = RunConfig(task=args.task, seeds=(0,), steps=10**7, eval_every=10**9, eval_episodes=1, threads=1,
                       actor=actor_config(args.preset), training=TrainingConfig(start_steps=0, update_after=100),
                       compile="on", matmul=args.matmul)
    with tempfile.TemporaryDirectory() as folder:
        trainer = Trainer(config, Path(folder) / "run", progress=False, log=lambda *_: None)
        try:
            for _ in range(400):
                trainer.train_step()
            step_us = mean_us(trainer.train_step, 1000)
            observations = trainer.environments.observations
            act_us = mean_us(lambda: trainer._act(observations), 1000)
            action = trainer._act(observations)
            env = trainer.environments.envs[0]

            def env_step() -> None:
                _, _, terminated, truncated, _ = env.step(action[0])
                if terminated or truncated:
                    env.reset()

            env_us = mean_us(env_step, 500)
            sample_us = mean_us(lambda: trainer.agent.to_batch(sample_minibatch(trainer.replay, trainer.normalizer,
                                                                                trainer.rngs, config.training)), 500)
            batch = trainer.agent.to_batch(sample_minibatch(trainer.replay, trainer.normalizer, trainer.rngs,
                                                            config.training))
            update_us = mean_us(lambda: trainer.agent.update(batch), args.updates)
            path = trainer.matmul_choice["path"]
        finally:
            trainer.close()
    matmul_us = 1e6 / matmul_floor(args.task, args.preset, (0,), 1, path)  # one step's products, act included
    rest_us = step_us - act_us - env_us - sample_us - update_us
    rows = [(f"update: matrix products ({path}; replayed alone)", matmul_us),
            ("update: everything else (fused kernels, program calls)", update_us - matmul_us),
            ("acting (batch 1, compiled)", act_us),
            ("environment step", env_us),
            ("replay sampling + normalisation", sample_us),
            ("the rest, by difference (replay writes, normaliser, noise, loss sums)", rest_us)]
    print(f"{args.preset} on {args.task}, {args.matmul}, 1 thread: {step_us:.0f} µs per training step "
          f"({1e6 / step_us:.0f} steps/s)\n")
    print("| part | µs per step | share |")
    print("|---|---|---|")
    for name, value in rows:
        print(f"| {name} | {value:.0f} | {100 * value / step_us:.0f}% |")


if __name__ == "__main__":
    main()
