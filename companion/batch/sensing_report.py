"""`uavsearch sensing-study`'s outputs: the study flown (`sensing_study`), its files and tables.

`study` writes into its folder: study.json, cells/*.csv (per-run rows, as cells finish),
summary.csv, paired.csv, pos_curves.csv, pos_<mission>.png, confirm_<mission>.png and
results_table.md (markdown tables for docs/results.md, "Imperfect sensing").
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import msgspec

from companion.batch import sensing_plots
from companion.batch.executors import RunExecutor
from companion.batch.sensing_study import (
    CellSummary,
    Definition,
    PairedRow,
    fly,
    grid,
    open_folder,
    paired_rows,
    summaries,
    write_pos_curves,
    write_table,
)
from companion.contracts.mission import ALGORITHMS, Mission


class SensingStudy(msgspec.Struct, frozen=True):
    """What `study` returns: its definition, per-cell summaries and paired differences."""

    definition: Definition
    summaries: list[CellSummary]
    paired: list[PairedRow]


def study(
    missions: Sequence[Mission],
    definition: Definition,
    out: Path,
    executor: RunExecutor,
    progress: bool = True,
) -> SensingStudy:
    """Fly (or read back) every cell of the Pd x Pf grid over the missions, and write the outputs."""
    for a in definition.algorithms:
        if a not in ALGORITHMS:
            raise ValueError(f"unknown algorithm {a!r}; choose from {', '.join(ALGORITHMS)}")
    names = [m.name for m in missions]
    if len(set(names)) != len(names):
        raise ValueError(
            f"two missions have the same name ({', '.join(names)}): the cells need distinct names"
        )
    open_folder(out, definition)
    cells = grid(missions, definition.pd, definition.pf)
    flown = fly(cells, definition.algorithms, definition, out, executor, progress)
    rows = list(summaries(flown))
    paired = [p for c in cells for p in paired_rows(flown[c.name], definition.algorithms)]
    write_table(out / "summary.csv", rows)
    write_table(out / "paired.csv", paired)
    write_pos_curves(out / "pos_curves.csv", flown)
    for m in missions:
        sensing_plots.plot_pos_grid(out / f"pos_{m.name}.png", m.name, definition.pd, definition.pf, flown)
        sensing_plots.plot_metrics(out / f"confirm_{m.name}.png", m.name, rows)
    result = SensingStudy(definition, rows, paired)
    (out / "results_table.md").write_text(markdown(result))
    return result


def _interval(low: float, high: float) -> str:
    return "n/a" if math.isnan(low) else f"[{low:+.1f}, {high:+.1f}]"


def markdown(result: SensingStudy) -> str:
    """Markdown tables of the study, per mission: the cells' metrics and the paired differences."""
    d = result.definition
    baselines = [a for a in d.algorithms if a != "proposed"]
    lines = []
    for mission in dict.fromkeys(s.mission for s in result.summaries):
        mine = [s for s in result.summaries if s.mission == mission]
        steps = mine[0].steps
        lines += [
            f"#### {mission} ({d.runs} runs per algorithm and cell, {steps} steps)",
            "",
            "| Pd | Pf | algorithm | time to confirmed detection | false confirmations / run "
            f"| never confirmed / run | POS at k = {steps // 4} | POS at k = {steps // 2} "
            f"| POS at k = {steps - 1} |",
            "|---:|---:|---|---:|---:|---:|---:|---:|---:|",
        ]
        lines += [
            f"| {s.pd:g} | {s.pf:g} | {s.algorithm} | {s.confirm_time:.1f} ± {s.confirm_time_ci95:.1f} "
            f"| {s.false_confirmations:.2f} ± {s.false_confirmations_ci95:.2f} "
            f"| {s.never_confirmed:.2f} ± {s.never_confirmed_ci95:.2f} "
            f"| {s.pos_quarter:.3f} | {s.pos_half:.3f} | {s.pos_end:.3f} |"
            for s in mine
        ]
        paired = [p for p in result.paired if p.mission == mission]
        if paired and baselines:
            lines += [
                "",
                "Proposed - baseline, time to a confirmed detection (steps; paired run by run, 95 % t "
                "interval; negative: the proposed method confirms sooner):",
                "",
                "| Pd | Pf | " + " | ".join(f"vs {b}" for b in baselines) + " |",
                "|---:|---:|" + "---:|" * len(baselines),
            ]
            for pd, pf in dict.fromkeys((p.pd, p.pf) for p in paired):
                cell = {p.baseline: p for p in paired if (p.pd, p.pf) == (pd, pf)}
                shown = [
                    f"{cell[b].difference:+.1f} {_interval(cell[b].difference_low, cell[b].difference_high)}"
                    for b in baselines
                ]
                lines.append(f"| {pd:g} | {pf:g} | " + " | ".join(shown) + " |")
        lines.append("")
    return "\n".join(lines)
