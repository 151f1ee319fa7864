"""Two checkouts of ilcsan, the same files: does the newer read what the older wrote, and act on it alike?

For a change that must not alter what the package reads and computes (a refactor), this trains short runs with
checkout A (``ilcsan train`` as a whole process, ``PYTHONPATH=<checkout>/src``): plain ILC-SAN, CaRe-BN (persistent
buffers, folded at export) and SAC (two readouts per action, one deployed). Then, in one process per checkout, it
loads each run's ``policy.pt``, acts on fixed observations and builds the deploy bundle's arrays, and loads every
committed bundle under ``docs/actors`` into the numpy runtime and acts; the two checkouts' actions and arrays must
be equal to the last bit. Finally checkout B resumes each of A's checkpoints for one more evaluation, and both
checkouts write ``ilcsan report`` of ``docs/paper-table/runs``, whose tables (report.csv) must be equal.

    git worktree add /tmp/before main~3
    .venv/bin/python benchmarks/format_check.py /tmp/before .
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

RUNS = {
    "ilc-san": [],
    "care-bn": ["--normalization", "care-bn"],
    "sac": ["--algorithm", "sac"],
}
STEPS = 1500

PROBE = r"""
import glob, hashlib, json, sys
import numpy as np
import ilcsan
from ilcsan.deploy.bundle import bundle_arrays
try:
    from ilcsan.runtime import DeployedActor
except ImportError:
    from ilcsan.deploy.runtime import DeployedActor

def digest(array):
    return hashlib.sha256(np.ascontiguousarray(array).tobytes()).hexdigest()[:16]

found = {}
for path in sys.argv[2:]:
    policy = ilcsan.load(path)
    rng = np.random.default_rng(0)
    observations = policy.obs_mean + policy.obs_std * rng.normal(0.0, 1.5, (16, policy.state_dim))
    found[path] = {"actions": digest(policy.predict(observations)),
                   "bundle": {name: digest(array) for name, array in sorted(bundle_arrays(policy).items())}}
for path in sorted(glob.glob(sys.argv[1] + "/docs/actors/*.npz")):
    actor = DeployedActor.load(path)
    rng = np.random.default_rng(0)
    observations = actor.obs_mean + actor.obs_std * rng.normal(0.0, 1.5, (16, len(actor.obs_mean)))
    found[path.rsplit("/", 1)[-1]] = {"actions": digest(actor.act(observations))}
print(json.dumps(found, sort_keys=True))
"""


def run(checkout: Path, *arguments: str, python: str = sys.executable) -> str:
    """A process with ``checkout``'s sources first on the path; its standard output (a failure stops the check)."""
    env = {**os.environ, "PYTHONPATH": str(checkout.resolve() / "src")}
    done = subprocess.run([python, *arguments], env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{checkout}: {' '.join(arguments)[:120]} failed:\n{done.stderr[-2000:]}")
    return done.stdout


def cli(checkout: Path, *arguments: str) -> str:
    return run(checkout, "-c", "import sys; from ilcsan.cli import main; sys.exit(main())", *arguments)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("before", type=Path, help="checkout A, which writes the files")
    parser.add_argument("after", type=Path, help="checkout B, which must read them alike")
    options = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        folders = {}
        for name, extra in RUNS.items():
            folders[name] = Path(scratch) / name
            cli(options.before, "train", "--task", "Hopper", "--seeds", "0", "--steps", str(STEPS), "--eval-every",
                str(STEPS // 3), "--eval-episodes", "1", "--start-steps", "500", "--update-after", "500",
                "--threads", "1", "--compile", "off", "--no-progress", "--out", str(folders[name]), *extra)
        policies = [str(folder / "policy.pt") for folder in folders.values()]
        seen = {side: json.loads(run(checkout, "-c", PROBE, str(options.after.resolve()), *policies))
                for side, checkout in (("A", options.before), ("B", options.after))}
        for key in seen["A"]:
            verdict = "equal" if seen["A"][key] == seen["B"].get(key) else "DIFFERENT"
            print(f"{Path(key).parent.name or key:>34}: actions and bundle arrays {verdict}", flush=True)
        for name, folder in folders.items():
            cli(options.after, "train", "--task", "Hopper", "--seeds", "0", "--steps", str(STEPS + STEPS // 3),
                "--eval-every", str(STEPS // 3), "--eval-episodes", "1", "--start-steps", "500", "--update-after",
                "500", "--threads", "1", "--compile", "off", "--no-progress", "--out", str(folder), "--resume",
                *RUNS[name])
            rows = (folder / "metrics.csv").read_text().strip().splitlines()
            print(f"{name:>34}: B resumed A's checkpoint at {STEPS} and evaluated at {rows[-1].split(',')[0]}")
        tables = {}
        for side, checkout in (("A", options.before), ("B", options.after)):
            out = Path(scratch) / f"report-{side}"
            cli(checkout, "report", str(options.after.resolve() / "docs" / "paper-table" / "runs"), "--table", "perf",
                "--out", str(out))
            tables[side] = (out / "report.csv").read_text()
        print(f"{'docs/paper-table report.csv':>34}: {'equal' if tables['A'] == tables['B'] else 'DIFFERENT'}")


if __name__ == "__main__":
    main()
