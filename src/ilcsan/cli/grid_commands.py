"""The commands that work on many runs: reproduce (grids of runs), report (tables and curves), energy."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from .. import load
from ..config import RunConfig, described_fields, training_config_class
from ..errors import UserError
from ..paper.layouts import TABLES
from .options import parse_seeds


def _split(text: str | None) -> tuple[str, ...] | None:
    if text is None:
        return None
    names = tuple(part.strip() for part in text.split(",") if part.strip())
    return names or None


def options_from_args(args):
    """The grid options of parsed ``reproduce`` arguments: the run and training settings are those it has options
    for."""
    from ..experiments.grid import GridOptions

    return GridOptions(seeds=None if args.seeds is None else parse_seeds(args.seeds), tasks=_split(args.tasks),
                       rows=_split(args.rows), run=_given(args, RunConfig),
                       training=_given(args, training_config_class()))


def _given(args, config_class: type) -> dict:
    """The settings of ``config_class`` that parsed arguments carry (None: not given, the grid's or the default)."""
    return {item.name: getattr(args, item.name) for item in described_fields(config_class)
            if getattr(args, item.name, None) is not None}


def cmd_reproduce(args) -> int:
    """``ilcsan reproduce TABLE|GRID.toml [options]`` and ``ilcsan reproduce --list``."""
    from ..experiments.backends import check_backend_options
    from ..experiments.coordinator import run_grid
    from ..experiments.estimate import list_tables
    from ..experiments.grid import expand_grid, table_to_reproduce

    if args.list:  # a named table as --seeds, --steps, --tasks, --rows shrink it
        specs = ([expand_grid(table_to_reproduce(args.table)[0], args.out, options_from_args(args)).spec]
                 if args.table else None)
        print(list_tables(specs, cores=args.workers))
        return 0
    if not args.table:
        raise UserError(f"name a table to reproduce ({', '.join(TABLES)}) or a grid file (.toml); "
                        "`ilcsan reproduce --list` shows them")
    check_backend_options(args.backend, args.address)
    spec, layout = table_to_reproduce(args.table)
    grid = expand_grid(spec, args.out, options_from_args(args), layout)
    from ..rl.validation import validate_run
    from ..runs.directory import RunDirectory

    if grid.runs:  # a bad --matmul: one line before any worker starts (devices are checked by the workers)
        validate_run(dataclasses.replace(grid.runs[0].config, device="cpu"))
    RunDirectory(grid.root).check_writable()  # an unwritable or full --out: one line before any worker starts
    summary = run_grid(grid, args.backend, args.workers, args.address, dashboard=args.dashboard)
    if summary.interrupted:
        return 130
    if summary.failed:
        return 3 if summary.diverged else 1
    return 0


def parse_steps(text: str) -> tuple[int, ...]:
    """``--collapse 30000,50000`` → (30000, 50000); a UserError for anything but positive whole numbers."""
    try:
        steps = tuple(int(part.replace("_", "")) for part in text.split(",") if part.strip())
    except ValueError:
        steps = ()
    if not steps or any(step < 1 for step in steps):
        raise UserError(f"--collapse {text!r}: give positive step numbers separated by commas, e.g. 30000,50000")
    return steps


def cmd_report(args) -> int:
    """``ilcsan report DIR [DIR...] [--table NAME|GRID.toml] [--out DIR]``: write the report, print where it is, how
    its cells stand beside the paper's and what tells its rows apart."""
    from ..analysis.collect import folders_of, scan_runs
    from ..analysis.comparison import Bootstrap
    from ..analysis.report import comparison_lines, runs_of_seeds, write_scanned_report
    from ..experiments.grid import report_layout

    folders = folders_of(args.directory)
    where = ", ".join(map(str, folders))
    if len(folders) > 1 and not args.out:
        raise UserError(f"a report of {len(folders)} folders needs --out DIR: where to write it")
    scan = scan_runs(folders)
    if not scan.runs:
        raise UserError(_no_runs_message(where, scan.skipped))
    seeds = parse_seeds(args.seeds) if args.seeds else None
    runs = runs_of_seeds(scan.runs, seeds)
    if not runs:
        found = sorted({run.seed for run in scan.runs})
        raise UserError(f"no runs of seeds {args.seeds} below {where}; the runs there have seeds "
                        f"{', '.join(map(str, found))}")
    table = report_layout(args.table, runs)
    collapse_steps = parse_steps(args.collapse) if args.collapse else ()
    bootstrap = Bootstrap(args.bootstrap_reps, args.bootstrap_seed)
    try:
        written = write_scanned_report(scan, Path(args.out) if args.out else folders[0], table, collapse_steps,
                                       args.collapse_return, seeds, bootstrap)
    except OSError as error:  # --out is a file, read-only, full, ...
        raise UserError(f"cannot write the report to {args.out or where}: {error.strerror or error}; "
                        "choose another --out") from None
    print(f"ilcsan report: {len(scan.runs)} run(s) found below {where}"
          + (f", {len(runs)} of seeds {args.seeds} reported" if seeds is not None else "")
          + (f", {len(scan.skipped)} skipped (listed in report.md)" if scan.skipped else ""))
    for kind, path in written.paths.items():
        print(f"  {kind:<10} {path}")
    comparisons = [line for result in written.results for line in comparison_lines(result)]
    if comparisons:
        print("beside the paper (our mean against the published mean ± std):")
        print("\n".join(f"  {line}" for line in comparisons))
    for comparison in written.comparisons:
        sentences = comparison.sentences()
        if sentences:
            print(f"telling the rows of {comparison.table} apart ({comparison.bootstrap.text}):")
            print("\n".join(f"  {sentence}" for sentence in sentences))
    return 0


def _no_runs_message(directory, skipped) -> str:
    """Why ``ilcsan report`` has nothing to report: no run below ``directory``, or none it could read."""
    if skipped:
        first = skipped[0]
        return f"no usable run below {directory}: {len(skipped)} skipped, e.g. {first.path}: {first.reason}"
    return (f"no runs below {directory}: a run is a folder with config.json and metrics.csv, as `ilcsan train "
            "--out DIR` writes; pass the folder you trained into")


def cmd_energy(args) -> int:
    """``ilcsan energy RUN [RUN...] --episodes 1 --seed 0 [--json]``."""
    from ..analysis.energy import COSTS, measure_energy
    from ..analysis.energy_tables import average_reports, energy_table, format_report

    reports = [measure_energy(load(run), args.episodes, args.seed, source=str(run)) for run in args.runs]
    if args.json:
        print(json.dumps({"runs": [r.to_dict() for r in reports],
                          "averaged": [r.to_dict() for r in average_reports(reports)],
                          "costs": [c._asdict() for c in COSTS]}, indent=2))
        return 0
    print("\n\n".join(format_report(r) for r in reports))
    if len(reports) > 1:
        print("\n" + energy_table(reports))
    return 0
