"""Run by the Sinabs test in Sinabs's own Python (.venv-sinabs: sinabs 3.1.3, nir 1.0.4): every ``*.nir`` graph
(target ``sinabs``) in a folder, read with nir 1.0.4 and run by :func:`ilcsan.deploy.nir.consumers.sinabs_module` on
that graph's observations (``<name>.obs.npy``, as one batch), and the documented Sinabs snippet (``snippet.py``)
as written on the observations in ``snippet/`` (one at a time, from ``snippet/actor.nir``); writes ``results.json``:
the actions and the versions that computed them."""

import contextlib
import io
import json
import os
import sys
import warnings
from pathlib import Path

import nir
import numpy as np
import sinabs

from ilcsan.deploy.nir import host_decode, host_encode, read_host
from ilcsan.deploy.nir.consumers import run_module, sinabs_module


def main(folder: Path) -> None:
    warnings.simplefilter("ignore", DeprecationWarning)  # nirtorch 2.0.2 warns that its load is deprecated
    results = {"versions": {"sinabs": sinabs.__version__, "nir": nir.version}, "actions": {}}
    for path in sorted(folder.glob("*.nir")):
        graph = nir.read(path)
        host = read_host(graph)
        observations = np.load(folder / f"{path.stem}.obs.npy")
        spikes = np.stack([host_encode(host, observation) for observation in observations], axis=1)
        outputs = run_module(sinabs_module(graph), spikes)
        results["actions"][path.stem] = [host_decode(host, outputs[:, index]).tolist()
                                         for index in range(len(observations))]
    code = (folder / "snippet.py").read_text()
    os.chdir(folder / "snippet")
    snippet = []
    for observation in np.load("observations.npy"):
        scope = {"observation": observation}
        with contextlib.redirect_stdout(io.StringIO()):
            exec(code, scope)  # noqa: S102 - the documented snippet, as a user runs it
        snippet.append(np.asarray(scope["action"]).tolist())
    results["snippet"] = snippet
    (folder / "results.json").write_text(json.dumps(results))


if __name__ == "__main__":
    main(Path(sys.argv[1]))
