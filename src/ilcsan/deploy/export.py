"""``ilcsan export``: a trained run's policy as a deploy bundle (:mod:`ilcsan.deploy.bundle`) or a NIR graph
(:mod:`ilcsan.deploy.nir`), written atomically beside the run unless told otherwise."""

from __future__ import annotations

from pathlib import Path

from ..config import EXPORT_FORMATS
from ..errors import UserError
from .bundle import WEIGHTS, export_npz
from .policy import load

FORMATS = tuple(EXPORT_FORMATS)


def export(run: str | Path, format: str = "npz", out: Path | None = None, weights: str = "float32",
           target: str = "portable") -> Path:
    """Export the policy of ``run`` in ``format`` to ``out`` (default ``<run>/actor.<format>``); ``target`` selects
    the NIR profile (:data:`ilcsan.deploy.nir.TARGETS`: portable = the LI integrator on the host, generic = in
    the graph, sinabs = portable in Sinabs's steps, nir 1.0.4-readable)."""
    if format not in FORMATS:
        raise UserError(f"--format {format!r} is not one of: {', '.join(FORMATS)}")
    if weights not in WEIGHTS:
        raise UserError(f"--weights {weights!r} is not one of: {', '.join(WEIGHTS)}")
    policy = load(run)
    run_path = Path(run)
    folder = run_path if run_path.is_dir() else run_path.parent
    suffix = "" if weights == "float32" else f".{weights}"
    out = Path(out) if out is not None else folder / f"actor{suffix}.{format}"
    if "\x00" in str(out):
        raise UserError(f"--out {str(out)!r} contains a NUL byte; choose another --out")
    if out.is_dir():  # --out FOLDER: the default file name inside it
        out = out / f"actor{suffix}.{format}"
    try:
        if format == "nir":
            from .nir import export_nir  # needs the nir package; a bundle does not

            return export_nir(policy, out, target)
        return export_npz(policy, out, weights)
    except OSError as error:
        raise UserError(f"cannot write {out}: {error.strerror or error}; choose another --out") from None
