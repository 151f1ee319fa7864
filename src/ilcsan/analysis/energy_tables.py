"""Tables fr, op and power of Section V-F in the paper's layout, and one run's energy report as text."""

from __future__ import annotations

import statistics
from collections.abc import Iterable, Sequence

from ..errors import UserError
from ..paper.published import ENERGY_TASKS
from .energy import COSTS, GROUP_FC, INTRA_FC, EnergyCosts, EnergyReport, LayerCount, analytic_report

LABELS = {"dan": "DAN", "popsan": "PopSAN", "ilc-san": "ILC-SAN", "mdc-san": "MDC-SAN", "akl": "Akl et al."}
"""The paper's name of each actor preset, in the order of Table power's columns."""
TASK_ORDER: tuple[str, ...] = ENERGY_TASKS
"""The tasks of Tables fr, op and power in the paper's order (other tasks follow alphabetically)."""


def average_reports(reports: Iterable[EnergyReport]) -> list[EnergyReport]:
    """One report per (actor, task): rates and counts averaged over runs (the paper averages 10 seeds)."""
    groups: dict[tuple[str, str], list[EnergyReport]] = {}
    for report in reports:
        groups.setdefault((report.label, report.task), []).append(report)
    averaged = []
    for group in groups.values():
        first = group[0]
        if len(group) == 1:
            averaged.append(first)
            continue
        if any([layer.name for layer in r.layers] != [layer.name for layer in first.layers] for r in group):
            raise UserError(f"runs of {first.label} on {first.task} have different layers; compare like with like")
        layers = []
        for index, layer in enumerate(first.layers):
            members = [r.layers[index] for r in group]
            rate = None if layer.rate is None else statistics.fmean(m.rate for m in members)
            layers.append(layer._replace(rate=rate, sop=statistics.fmean(m.sop for m in members),
                                         flop=statistics.fmean(m.flop for m in members)))
        averaged.append(EnergyReport(first.label, first.task, first.state_dim, first.action_dim, first.timesteps,
                                     tuple(layers), sum(r.inferences for r in group),
                                     ", ".join(r.source for r in group), len(group)))
    return averaged


def _task_key(task: str) -> tuple[int, str]:
    return (TASK_ORDER.index(task) if task in TASK_ORDER else len(TASK_ORDER), task)


def _label_key(label: str) -> tuple[int, str]:
    order = list(LABELS)
    return (order.index(label) if label in order else len(order), label)


def _markdown(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(" --- " for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def _ops(layer: LayerCount) -> str:
    return f"{layer.sop:.0f} SOP" if layer.input_kind == "spikes" else f"{layer.flop:.0f} FLOP"


def _total(report: EnergyReport) -> str:
    parts = []
    if report.total_sop or report.total_flop == 0:
        parts.append(f"{report.total_sop:.0f} SOP")
    if report.total_flop:
        parts.append(f"{report.total_flop:.0f} FLOP")
    return " + ".join(parts)


def energy_table(reports: Iterable[EnergyReport], costs: Sequence[EnergyCosts] = COSTS) -> str:
    """Tables fr, op and power in the paper's layout (markdown), runs of one actor/task averaged.

    Table power has a column per actor (DAN, PopSAN, ILC-SAN, …); a DAN column missing for a task is
    filled analytically (a DAN's FLOP count does not depend on its weights) and marked with *.
    """
    averaged = sorted(average_reports(reports), key=lambda r: (_task_key(r.task), _label_key(r.label)))
    if not averaged:
        raise UserError("no runs to tabulate")
    spiking = [r for r in averaged if r.label != "dan" and any(lay.input_kind != "dense" for lay in r.layers)]
    sections = _rate_and_operation_tables(spiking) if spiking else []
    sections += [_power_table(averaged, cost) for cost in costs]
    return "\n\n".join(sections)


def _rate_and_operation_tables(spiking: Sequence[EnergyReport]) -> list[str]:
    """Tables fr and op: one line per spiking actor and task, one column per synaptic layer."""
    columns: list[str] = []
    for report in spiking:
        columns += [layer.name for layer in report.layers if layer.name not in columns]
    columns.sort(key=lambda name: (name in (GROUP_FC, INTRA_FC), name == INTRA_FC, len(name), name))
    fr_rows, op_rows = [], []
    for report in spiking:
        by_name = {layer.name: layer for layer in report.layers}
        label = LABELS.get(report.label, report.label)
        fr_rows.append([report.task, label] + [
            "−" if by_name.get(c) is None or by_name[c].rate is None else f"{100 * by_name[c].rate:.1f}%"
            for c in columns])
        op_rows.append([report.task, label] + [_ops(by_name[c]) if c in by_name else "−" for c in columns]
                       + [_total(report)])
    return ["Table fr: average firing rate of the neuronal layer before each FC layer\n\n"
            + _markdown(["Task", "Actor Network", *columns], fr_rows),
            "Table op: operations per inference of each FC layer\n\n"
            + _markdown(["Task", "Actor Network", *columns, "Total"], op_rows)]


def _power_table(averaged: Sequence[EnergyReport], cost: EnergyCosts) -> str:
    """Table power under one cost model: a line per task, a column per actor (DAN filled analytically)."""
    tasks = sorted({r.task for r in averaged}, key=_task_key)
    labels = sorted({r.label for r in averaged} | {"dan"}, key=_label_key)
    by_key = {(r.task, r.label): r for r in averaged}
    rows, analytic = [], False
    for task in tasks:
        row = [task]
        for label in labels:
            report = by_key.get((task, label))
            if report is None and label == "dan":
                some = next(r for r in averaged if r.task == task)
                report = analytic_report("dan", task, some.state_dim, some.action_dim, source="analytic")
                row.append(f"{report.energy_nj(cost):.1f}*")
                analytic = True
            else:
                row.append("−" if report is None else f"{report.energy_nj(cost):.1f}")
        rows.append(row)
    note = "\n\n* DAN computed from the task's dimensions (2×256 hidden), not from a run." if analytic else ""
    return (f"Table power: energy per inference in nJ, {cost.name}\n\n"
            + _markdown(["Task", *(LABELS.get(label, label) for label in labels)], rows) + note)


def format_report(report: EnergyReport) -> str:
    """One run: firing rate and operations per layer, totals, nJ per inference under each cost model."""
    label = LABELS.get(report.label, report.label)
    measured = f", {report.inferences} inferences" if report.inferences else ""
    header = f"{report.source or report.task}: {label} on {report.task} (T = {report.timesteps}{measured})"
    rows = [[layer.name, layer.shape, layer.input_kind,
             "−" if layer.rate is None else f"{100 * layer.rate:.1f}%", _ops(layer)] for layer in report.layers]
    table = _markdown(["Layer", "(Din, Dout)", "Input", "fr_in", "Operations"], rows)
    energy = "; ".join(f"{report.energy_nj(cost):.2f} nJ ({cost.name})" for cost in COSTS)
    return f"{header}\n\n{table}\n\nTotal: {_total(report)} per inference\nEnergy per inference: {energy}"
