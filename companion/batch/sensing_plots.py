"""PNG plots of `uavsearch sensing-study`: POS curves over the Pd x Pf grid, and the metrics vs Pd."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from companion.batch.plots import COLOURS
from companion.batch.sensing_study import CellSummary, RunRow, by_algorithm, pos_band

PF_STYLES = ("-", "--", ":", "-.")


def plot_pos_grid(
    path: Path,
    mission: str,
    pds: Sequence[float],
    pfs: Sequence[float],
    flown: Mapping[str, Sequence[RunRow]],
) -> None:
    """One mission's POS curves (mean, 95 % band) per algorithm: a panel per Pd (rows) and Pf (columns)."""
    fig, axes = plt.subplots(
        len(pds), len(pfs), figsize=(4.2 * len(pfs), 3.2 * len(pds)), sharex=True, sharey=True, squeeze=False
    )
    cells = {(r[0].pd, r[0].pf): r for r in flown.values() if r and r[0].mission == mission}
    for i, pd in enumerate(pds):
        for j, pf in enumerate(pfs):
            ax = axes[i, j]
            for name, rows in by_algorithm(cells[(pd, pf)]).items():
                mean, ci = pos_band(rows)
                k = np.arange(len(mean))
                ax.plot(k, mean, color=COLOURS.get(name), label=name)
                ax.fill_between(k, mean - ci, mean + ci, color=COLOURS.get(name), alpha=0.25)
            ax.set_title(f"Pd = {pd:g}, Pf = {pf:g}", fontsize=9)
            ax.set_ylim(0, 1.02)
            ax.grid(alpha=0.3)
            if i == len(pds) - 1:
                ax.set_xlabel("sampling moment k")
            if j == 0:
                ax.set_ylabel("POS (targets confirmed)")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"{mission}: probability of success under imperfect sensing")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_metrics(path: Path, mission: str, rows: Sequence[CellSummary]) -> None:
    """One mission's time to a confirmed detection and false confirmations per run against Pd.

    A line per algorithm (colour) and Pf (line style), with 95 % error bars.
    """
    mine = [r for r in rows if r.mission == mission]
    pfs = sorted({r.pf for r in mine})
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.5))
    for name in dict.fromkeys(r.algorithm for r in mine):
        for n, pf in enumerate(pfs):
            line = sorted((r for r in mine if r.algorithm == name and r.pf == pf), key=lambda r: r.pd)
            pd = [r.pd for r in line]
            style = dict(
                color=COLOURS.get(name), linestyle=PF_STYLES[n % len(PF_STYLES)], marker="o", capsize=3
            )
            label = f"{name}, Pf = {pf:g}"
            a.errorbar(
                pd,
                [r.confirm_time for r in line],
                yerr=[r.confirm_time_ci95 for r in line],
                label=label,
                **style,
            )
            b.errorbar(
                pd,
                [r.false_confirmations for r in line],
                yerr=[r.false_confirmations_ci95 for r in line],
                **style,
            )
    a.set_ylabel("mean time to a confirmed detection (steps)")
    b.set_ylabel("false confirmations per run")
    for ax in (a, b):
        ax.set_xlabel("Pd")
        ax.grid(alpha=0.3)
    a.legend(fontsize=7)
    fig.suptitle(f"{mission}: confirmed detections against Pd and Pf")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
