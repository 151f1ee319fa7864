"""``python -m ilcsan.deploy.lava BUNDLE``: a deploy bundle in Lava's simulator of Loihi 2, closed loop on its task.

Runs in the Lava environment (``scripts/setup-lava``); ``ilcsan lava`` exports a run's bundle and calls this. The
host does what it does for NIR: normaliser, encoder, the decoder's statistic and tanh; the network (every synaptic
layer, the intra-layer connections, the biases, the LI readout) runs as Lava processes. Prints each episode's
return and time, and with ``--check N`` the largest action error against the bundle's numpy runtime over the first
N observations the episodes visit. User mistakes print one line and exit with code 2.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from ...runtime import DeployedActor
from ...runtime.errors import UserError
from . import run_options
from .plan import encoder_spikes, fix_plan, host_action, plan_actor, simulate

EXIT_USER_ERROR = 2
CALIBRATION_SEED = 10_000
"""Environment seed of the numpy-runtime episode whose observations set the fixed-point ranges (not an
evaluation seed)."""
CALIBRATION_OBSERVATIONS = 200
ENGINES = ("lava", "mirror", "numpy")
CHECK_TOLERANCE = 1e-5
"""``--check`` counts the actions that differ from the numpy runtime's by more than this."""


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m ilcsan.deploy.lava", parents=[run_options()],
                                     description="Run a deploy bundle in Lava (Loihi 2's SDK), closed loop.")
    parser.add_argument("bundle", help="deploy bundle (actor.npz from `ilcsan export`)")
    parser.add_argument("--engine", choices=ENGINES, default="lava",
                        help="lava (default); mirror: the same network with Lava's rules simulated in numpy "
                             "(ilcsan.deploy.lava.plan.simulate, equal to Lava in the tests; fast, no Lava needed); "
                             "numpy: the bundle's numpy runtime, for a like-for-like reference")
    return parser


def _episode_observations(actor: DeployedActor, task: str, seed: int, count: int) -> list[np.ndarray]:
    """Up to ``count`` observations of one episode the numpy runtime plays (the fixed-point calibration)."""
    from ...rl.tasks import make_env, trained_contact_forces

    env = make_env(task, seed=seed, contact_forces=trained_contact_forces(actor))
    observation, _ = env.reset(seed=seed)
    seen = [observation]
    for _ in range(10 * count):
        observation, _, terminated, truncated, _ = env.step(actor.act(observation))
        seen.append(observation)
        if terminated or truncated:
            break
    env.close()
    picked = np.linspace(0, len(seen) - 1, min(count, len(seen))).round().astype(int)
    return [seen[index] for index in picked]


def _calibration(args: argparse.Namespace, reference: DeployedActor, task: str) -> list[np.ndarray]:
    if not args.fixed_point:
        return []
    return [encoder_spikes(reference, observation) for observation in
            _episode_observations(reference, task, CALIBRATION_SEED, CALIBRATION_OBSERVATIONS)]


def _lava_actor(args: argparse.Namespace, actor: DeployedActor, reference: DeployedActor, task: str):
    try:
        from .network import LavaActor
    except ImportError as error:
        raise UserError(f"Lava is not importable here ({error}): run `bash scripts/setup-lava` and use "
                        ".venv-lava/bin/python (or `ilcsan lava`, which does)") from None
    return LavaActor(actor, fixed=args.fixed_point, calibration=_calibration(args, reference, task))


class _MirrorEngine:
    """The planned network run by :func:`~.plan.simulate` (``--engine mirror``), float or fixed point."""

    def __init__(self, args: argparse.Namespace, actor: DeployedActor, reference: DeployedActor, task: str):
        self.actor, self.plan = actor, plan_actor(actor)
        self.fixed = fix_plan(self.plan, _calibration(args, reference, task)) if args.fixed_point else None

    def act(self, observation: np.ndarray) -> np.ndarray:
        voltages, _ = simulate(self.plan, encoder_spikes(self.actor, observation), self.fixed)
        return host_action(self.actor, voltages)

    def close(self) -> None:
        pass


class _NumpyEngine:
    """The bundle's numpy runtime behind the Lava actor's two calls (``--engine numpy``)."""

    def __init__(self, actor: DeployedActor):
        self.act = actor.act

    def close(self) -> None:
        pass


def _write_json(result: dict, target: Path) -> None:
    """Replace ``target`` with ``result`` in one step (a file beside it, then a rename)."""
    partial = target.with_name(target.name + ".partial")
    partial.write_text(json.dumps(result, indent=2))
    partial.replace(target)


def _check_line(result: dict) -> str:
    return (f"largest action error against the numpy runtime over {result['checked_actions']} actions: "
            f"{result['max_action_error']:.3g} (median {result['median_action_error']:.3g}, 90th percentile "
            f"{result['p90_action_error']:.3g}; {result['actions_off']} off by more than {CHECK_TOLERANCE:g})")


def _summary(args: argparse.Namespace, task: str, returns: list[float], lengths: list[int], seconds: list[float],
             errors: list[float]) -> dict:
    """The results so far: per-episode returns, lengths and times, and the action check's statistics."""
    mode = "numpy runtime" if args.engine == "numpy" else \
        ("fixed_pt" if args.fixed_point else "floating_pt") + (", numpy mirror" if args.engine == "mirror" else "")
    return {"bundle": str(args.bundle), "task": task, "mode": mode,
            "episodes_done": len(returns), "episodes": args.episodes, "finished": len(returns) == args.episodes,
            "returns": returns, "lengths": lengths, "episode_seconds": seconds,
            "mean_return": float(np.mean(returns)), "std_return": float(np.std(returns)),
            "checked_actions": len(errors), "max_action_error": max(errors) if errors else None,
            "median_action_error": float(np.median(errors)) if errors else None,
            "p90_action_error": float(np.percentile(errors, 90)) if errors else None,
            "actions_off": sum(error > CHECK_TOLERANCE for error in errors)}


def run(args: argparse.Namespace) -> dict:
    """Play ``args.episodes`` episodes. After each one, the results so far are written to ``--json`` (atomically,
    ``finished`` false until the last), so a run cut short keeps its episodes; the ``--check`` line is printed as soon
    as its N actions are compared (or after the last episode, when the episodes visit fewer)."""
    from ...rl.tasks import make_env, trained_contact_forces

    actor = DeployedActor.load(Path(args.bundle))
    reference = DeployedActor.load(Path(args.bundle))
    task = args.task or str(actor.meta["task"])
    start = time.perf_counter()
    engine = (_NumpyEngine(actor) if args.engine == "numpy" else _MirrorEngine(args, actor, reference, task)
              if args.engine == "mirror" else _lava_actor(args, actor, reference, task))
    returns, lengths, seconds, errors = [], [], [], []
    check_printed = False
    try:
        for episode in range(args.episodes):
            env = make_env(task, seed=args.seed + episode, contact_forces=trained_contact_forces(actor))
            observation, _ = env.reset(seed=args.seed + episode)
            total, steps, began, done = 0.0, 0, time.perf_counter(), False
            while not done:
                action = engine.act(observation)
                if len(errors) < args.check:
                    errors.append(float(np.abs(action - reference.act(observation)).max()))
                observation, reward, terminated, truncated, _ = env.step(action)
                total, steps, done = total + float(reward), steps + 1, terminated or truncated
            env.close()
            returns.append(total)
            lengths.append(steps)
            seconds.append(time.perf_counter() - began)
            print(f"episode {episode + 1}/{args.episodes}: return {total:.1f}, {steps} steps, "
                  f"{seconds[-1]:.0f} s ({seconds[-1] / steps * 1e3:.0f} ms per action)", flush=True)
            result = _summary(args, task, returns, lengths, seconds, errors)
            result["wall_seconds"] = time.perf_counter() - start
            if getattr(engine, "fixed", None) is not None:
                result["worst_weight_error"] = engine.fixed.worst_weight_error
            if errors and not check_printed and (len(errors) == args.check or result["finished"]):
                print(_check_line(result), flush=True)
                check_printed = True
            if args.json:
                _write_json(result, Path(args.json))
    finally:
        engine.close()
    return result


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        result = run(args)
    except UserError as error:
        print(f"error: {error}", file=sys.stderr)
        return EXIT_USER_ERROR
    print(f"{result['task']} ({result['mode']}), {len(result['returns'])} episodes: average return "
          f"{result['mean_return']:.1f} ± {result['std_return']:.1f}, average length {np.mean(result['lengths']):.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
