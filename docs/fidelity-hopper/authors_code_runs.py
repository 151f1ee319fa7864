"""Row (c): the authors' code's evaluation lines as run folders that `ilcsan report` reads.

The authors' `hybrid_td3_cuda_norm.py` prints ``Model:  i  Steps:  s  Mean Reward:  r`` after each 10-episode
evaluation (every 10 000 steps) of model i, seeded with 10 · i. This writes, for each model, a folder
``grid/fidelity/Hopper/authors-code/seed<10·i>/`` with a ``config.json`` (task, seed, label, ILC-SAN's actor with
the authors' intra timing) and a ``metrics.csv`` (step, eval_return_mean). Usage:
``python docs/fidelity-hopper/authors_code_runs.py LOG... `` (the logs of the runs; nothing else is read).
"""

import csv
import json
import re
import sys
from pathlib import Path

from ilcsan.config import actor_config

LINE = re.compile(r"Model:\s+(\d+)\s+Steps:\s+(\d+)\s+Mean Reward:\s+(\S+)")
LABEL = "the authors' code (lucifer2859/ILC-SAN 5012a77, CPU + Gymnasium)"
ROOT = Path(__file__).parent / "grid" / "fidelity" / "Hopper" / "authors-code"
STEPS = 50_000


def main(logs: list[str]) -> None:
    evaluations: dict[int, dict[int, float]] = {}
    for log in logs:
        for model, step, value in LINE.findall(Path(log).read_text()):
            evaluations.setdefault(int(model), {})[int(step)] = float(value)
    for model, returns in sorted(evaluations.items()):
        if max(returns) < STEPS:
            print(f"model {model}: unfinished ({max(returns)} steps), skipped")
            continue
        folder = ROOT / f"seed{10 * model}"
        folder.mkdir(parents=True, exist_ok=True)
        config = {"task": "Hopper", "seed": 10 * model, "seeds": [10 * model], "label": LABEL, "steps": STEPS,
                  "actor": actor_config("ilc-san", intra_timing="authors").to_dict()}
        (folder / "config.json").write_text(json.dumps(config, indent=2) + "\n")
        with open(folder / "metrics.csv", "w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(["step", "eval_return_mean"])
            writer.writerows(sorted(returns.items()))
        print(f"model {model} (seed {10 * model}): {len(returns)} evaluations → {folder}")


if __name__ == "__main__":
    main(sys.argv[1:])
