"""Run by the Lava tests in Lava's own Python (.venv-lava): every ``*.npz`` bundle in a folder through Lava, float
and (for bundles listed in fixed.json) fixed point, on that bundle's observations (``<name>.obs.npy``); writes
``results.json``: Lava's float actions and spike counts per layer, and for fixed point the largest difference
between Lava's LI voltages and :func:`ilcsan.deploy.lava.plan.simulate`'s integer mirror."""

import json
import sys
from pathlib import Path

import numpy as np

from ilcsan.deploy import DeployedActor
from ilcsan.deploy.lava.network import LavaActor
from ilcsan.deploy.lava.plan import encoder_spikes, plan_actor, simulate


def main(folder: Path) -> None:
    fixed_names = set(json.loads((folder / "fixed.json").read_text()))
    results = {}
    for bundle in sorted(folder.glob("*.npz")):
        actor = DeployedActor.load(bundle)
        observations = np.load(folder / f"{bundle.stem}.obs.npy")
        lava = LavaActor(actor, monitor_steps=plan_actor(actor).block * len(observations))
        try:
            actions = [lava.act(observation).tolist() for observation in observations]
            counts = lava.spike_counts()
        finally:
            lava.close()
        result = {"actions": actions, "spikes": counts}
        if bundle.stem in fixed_names:
            calibration = [encoder_spikes(actor, observation) for observation in observations]
            lava = LavaActor(actor, fixed=True, calibration=calibration)
            try:
                gaps = [float(np.abs(lava.voltages(train) - simulate(lava.plan, train, lava.fixed)[0]).max())
                        for train in calibration]
            finally:
                lava.close()
            result["fixed_gap"] = max(gaps)
        results[bundle.stem] = result
    (folder / "results.json").write_text(json.dumps(results))


if __name__ == "__main__":
    main(Path(sys.argv[1]))
