"""PNG plots of the paper's figure panels (Figures 8-11)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.artist import Artist
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from companion.batch.confirmation import run_pos
from companion.batch.engine import RunResult
from companion.batch.montecarlo import Summary
from companion.batch.report import mean_band
from companion.core.world import World

if TYPE_CHECKING:
    from companion.batch.heldout import MissionFeatures, PairedTable
    from companion.batch.tune import Trial

COLOURS = {"proposed": "tab:red", "no-ta": "tab:blue", "pheromone": "tab:green"}
# one colour per UAV, none of them the regions' grey, the prior centres' red or the targets' black
UAV_COLOURS = (
    "tab:blue",
    "tab:green",
    "tab:purple",
    "tab:orange",
    "tab:brown",
    "tab:pink",
    "tab:olive",
    "tab:cyan",
)
REGION_COLOUR = "0.3"


def _lattice_image(world: World, values: np.ndarray) -> np.ndarray:
    g = world.grid
    img = np.full(g.lattice.shape, np.nan)
    inside = g.lattice >= 0
    img[inside] = values[g.lattice[inside]]
    return img


def _extent(world: World) -> tuple[float, float, float, float]:
    g = world.grid
    h = g.cell_size / 2
    return (g.x0 - h, g.x0 + g.cell_size * g.nx - h, g.y0 - h, g.y0 + g.cell_size * g.ny - h)


def _draw_prior(ax: plt.Axes, world: World) -> None:
    ax.imshow(
        _lattice_image(world, world.prior), origin="lower", extent=_extent(world), cmap="Greys", alpha=0.8
    )
    for c in world.mission.prior.centres:
        ax.plot(c.x, c.y, "*", color="red", markersize=10)
    ax.set_aspect("equal")
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")


def _draw_regions(ax: plt.Axes, world: World) -> None:
    t = world.tessellation
    if t is None:
        return
    g = world.grid
    lab = np.where(g.lattice >= 0, t.labels[g.lattice], -1)
    h = g.cell_size / 2
    segments = []
    rows, cols = np.nonzero(lab[:, 1:] != lab[:, :-1])  # vertical edges between columns c and c + 1
    for r, c in zip(rows, cols, strict=True):
        x = g.x0 + g.cell_size * c + h
        y = g.y0 + g.cell_size * r
        segments.append([(x, y - h), (x, y + h)])
    rows, cols = np.nonzero(lab[1:, :] != lab[:-1, :])  # horizontal edges between rows r and r + 1
    for r, c in zip(rows, cols, strict=True):
        x = g.x0 + g.cell_size * c
        y = g.y0 + g.cell_size * r + h
        segments.append([(x - h, y), (x + h, y)])
    ax.add_collection(LineCollection(segments, colors=REGION_COLOUR, linewidths=0.7, linestyles="dashed"))
    ax.plot(t.generators[:, 0], t.generators[:, 1], "x", color=REGION_COLOUR, markersize=3, linewidth=0.6)


def plot_prior(path: Path, world: World) -> None:
    """Figure 8(a)-10(a): the prior (eq. 1) with the CVT regions of Algorithm 1 and the start poses."""
    fig, ax = plt.subplots(figsize=(6, 6))
    _draw_prior(ax, world)
    _draw_regions(ax, world)
    for v in world.mission.vehicles:
        ax.plot(v.x, v.y, "^", color="black")
    ax.set_title(f"{world.mission.name}: prior and CVT regions (n_g = {world.mission.algorithm.n_g})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _search_start(tasks: np.ndarray | None, i: int) -> int:
    """The first step UAV i holds a task when that came after a wait, else 0.

    Before that step it loitered while the swarm started (a distributed run's companions come up
    one by one). It is 0 when the UAV held a task from the second step (every batch run), or
    without task records.
    """
    if tasks is None:
        return 0
    held = np.flatnonzero(tasks[:, i] >= 0)
    first = int(held[0]) if held.size else 0
    return first if first > 1 else 0


def _trajectory_legend(ax: plt.Axes, n: int, regions: bool, loitered: bool) -> None:
    line = Line2D
    handles: list[Artist] = [
        line([], [], color=UAV_COLOURS[i % len(UAV_COLOURS)], linewidth=1.2, label=f"UAV {i}")
        for i in range(n)
    ]
    if loitered:
        handles.append(line([], [], color="0.4", linestyle=":", label="start-up: loitering, no task yet"))
    handles += [
        line([], [], color="black", marker="^", linestyle="none", label="start position"),
        line([], [], color="black", marker="s", markerfacecolor="none", linestyle="none", label="target"),
        line([], [], color="red", marker="*", markersize=10, linestyle="none", label="prior centre"),
    ]
    if regions:
        handles += [
            line([], [], color=REGION_COLOUR, linestyle="--", linewidth=0.7, label="CVT region boundary"),
            line([], [], color=REGION_COLOUR, marker="x", linestyle="none", label="CVT generator"),
        ]
    handles.append(Patch(facecolor="0.35", label="prior probability (darker: higher)"))
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)


def plot_trajectories(
    path: Path,
    worlds: Mapping[str, World],
    runs: Mapping[str, RunResult],
    starts: Mapping[str, np.ndarray] | None = None,
) -> None:
    """Figures 8(b)-(d): one run's trajectories per algorithm over the prior, with the targets.

    The prior is grey (darker: higher probability). Each UAV has its own colour from its start
    (`starts[name]`, the UAVs' start positions; default: the first step's), and the steps it
    loitered before its first task are dotted. For the proposed method the plot shows the CVT
    regions it divides the area into.
    """
    width = 5.5 * len(runs) + 2.6
    fig, axes = plt.subplots(1, len(runs), figsize=(width, 5.5), squeeze=False)
    loitered = False
    for ax, (name, r) in zip(axes[0], runs.items(), strict=True):
        world = worlds[name]
        _draw_prior(ax, world)
        regions = name == "proposed" and world.tessellation is not None
        if regions:
            _draw_regions(ax, world)
        assert r.trajectory is not None
        first = starts[name] if starts is not None and name in starts else r.trajectory[0, :, :2]
        for i in range(r.trajectory.shape[1]):
            colour = UAV_COLOURS[i % len(UAV_COLOURS)]
            xy = r.trajectory[:, i, :2]
            k = _search_start(r.tasks, i)
            if k:
                loitered = True
                ax.plot(xy[: k + 1, 0], xy[: k + 1, 1], ":", color=colour, linewidth=1.0)
            ax.plot(xy[k:, 0], xy[k:, 1], color=colour, linewidth=0.9)
            ax.plot(first[i, 0], first[i, 1], "^", color="black", markersize=7)
        t = world.grid.centres[r.target_cells]
        ax.plot(t[:, 0], t[:, 1], "s", color="black", markersize=6, markerfacecolor="none")
        ax.set_title(f"{name} (run {r.run}, {r.steps} steps)")
    shown = runs[next(iter(runs))].trajectory
    assert shown is not None
    _trajectory_legend(axes[0, -1], shown.shape[1], "proposed" in runs, loitered)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _band(ax: plt.Axes, name: str, curves: np.ndarray) -> None:
    mean, ci = mean_band(curves)
    steps = np.arange(len(mean))
    ax.plot(steps, mean, color=COLOURS.get(name), label=name)
    ax.fill_between(steps, mean - ci, mean + ci, color=COLOURS.get(name), alpha=0.25)


def plot_uncertainty(path: Path, results: Mapping[str, Sequence[RunResult]]) -> None:
    """Figures 8(e)-10(e): mean global average uncertainty (eq. 30) with its 95 % confidence band."""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name, runs in results.items():
        _band(ax, name, np.array([r.uncertainty for r in runs]))
    ax.set_xlabel("sampling moment k")
    ax.set_ylabel("global average uncertainty")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_found(path: Path, results: Mapping[str, Sequence[RunResult]]) -> None:
    """Figures 8(f)-10(f): targets found vs step (mean over runs, 95 % band)."""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name, runs in results.items():
        _band(ax, name, np.array([r.found for r in runs], dtype=float))
    ax.set_xlabel("sampling moment k")
    ax.set_ylabel("targets found")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_pos(path: Path, results: Mapping[str, Sequence[RunResult]]) -> None:
    """The swarm's probability of success vs step: the fraction of targets confirmed (95 % band)."""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name, runs in results.items():
        _band(ax, name, np.array([run_pos(r) for r in runs]))
    ax.set_xlabel("sampling moment k")
    ax.set_ylabel("probability of success (targets confirmed)")
    ax.set_ylim(0, 1.02)
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_sweep(
    path: Path, param: str, values: Sequence[float], summaries: Sequence[Summary], safety: float
) -> None:
    """Figure 11: coverage and search efficiency, min lambda_2 and min distance against a parameter."""
    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    panels = [
        ("mean_uncertainty_over_run", "mean global average uncertainty", "(a) coverage efficiency"),
        ("mean_target_time", "mean time to find a target (steps)", "(b) search efficiency"),
        ("min_lambda2", "min lambda_2", "(c) connectivity"),
        ("min_distance", "min inter-UAV distance (m)", "(d) collision avoidance"),
    ]
    for ax, (key, label, title) in zip(axes.ravel(), panels, strict=True):
        y = [getattr(s, key) for s in summaries]
        err = [getattr(s, f"{key}_ci95", 0.0) for s in summaries]
        ax.errorbar(values, y, yerr=err, marker="o", capsize=3)
        if key == "min_distance":
            ax.axhline(safety, color="black", linestyle="--", label="R_s")
            ax.legend()
        if key == "min_lambda2":
            ax.axhline(0.0, color="black", linestyle="--")
        ax.set_xlabel(param)
        ax.set_ylabel(label)
        ax.set_title(title)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_links(path: Path, result: RunResult, safety: float) -> None:
    """lambda_2 and the minimum inter-UAV distance over one run (connectivity and safety)."""
    fig, (a, b) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    a.plot(result.lambda2)
    a.axhline(0.0, color="black", linestyle="--")
    a.set_ylabel("lambda_2")
    b.plot(result.min_distance)
    b.axhline(safety, color="black", linestyle="--", label="R_s")
    b.set_ylabel("min distance (m)")
    b.set_xlabel("sampling moment k")
    b.legend()
    for ax in (a, b):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _paired_panels(table: PairedTable, metrics: Sequence[str], height: float) -> tuple[Figure, list[tuple]]:
    """A grid of axes, a row per metric and a column per baseline, and each panel's paired data.

    A panel is (ax, baseline, metric, rows, difference, low, high): its per-mission rows of
    `heldout.paired_table` and their differences with 95 % intervals.
    """
    baselines = list(dict.fromkeys(row.baseline for row in table.overall))
    fig, axes = plt.subplots(
        len(metrics), len(baselines), figsize=(5.5 * len(baselines), height * len(metrics)), squeeze=False
    )
    panels = []
    for i, metric in enumerate(metrics):
        for j, baseline in enumerate(baselines):
            rows = [r for r in table.missions if r.baseline == baseline and r.metric == metric]
            rows.sort(key=lambda r: r.difference)
            d = np.array([r.difference for r in rows])
            lo = np.array([r.difference_low for r in rows])
            hi = np.array([r.difference_high for r in rows])
            panels.append((axes[i, j], baseline, metric, rows, d, lo, hi))
    return fig, panels


def plot_paired(path: Path, table: PairedTable, metrics: Sequence[str]) -> None:
    """`uavsearch evaluate`: the paired differences proposed - baseline, per baseline and metric.

    A panel shows, per mission, the difference with its 95 % interval (sorted), the overall mean
    difference (band) and the win rate.
    """
    fig, panels = _paired_panels(table, metrics, 4.5)
    for ax, baseline, metric, rows, d, lo, hi in panels:
        y = np.arange(len(rows))
        ax.errorbar(
            d, y, xerr=[d - lo, hi - d], fmt="o", markersize=3, color=COLOURS.get(baseline), capsize=2
        )
        o = next(r for r in table.overall if r.baseline == baseline and r.metric == metric)
        ax.axvspan(o.difference_low, o.difference_high, color="tab:red", alpha=0.2, label="overall 95 % CI")
        ax.axvline(o.difference, color="tab:red", label=f"overall mean {o.difference:.3g}")
        ax.axvline(0.0, color="black", linestyle="--")
        ax.set_yticks([])
        ax.set_ylabel("missions (sorted)")
        ax.set_xlabel(f"{metric}: proposed - {baseline} (lower: proposed better)")
        p, low, high = 100 * o.win_rate, 100 * o.win_rate_low, 100 * o.win_rate_high
        ax.set_title(f"vs {baseline}: wins {o.wins}/{o.missions} ({p:.0f} %, {low:.0f}-{high:.0f} %)")
        ax.legend(loc="lower right", fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_density(
    path: Path, table: PairedTable, info: Sequence[MissionFeatures], metrics: Sequence[str]
) -> None:
    """`uavsearch evaluate`: the paired differences against area per UAV, per baseline and metric.

    A panel shows each mission's paired difference proposed - baseline (95 % interval) against its
    area per UAV; the median area per UAV splits the missions into `heldout.by_density`'s halves.
    """
    per_uav = {i.mission: i.km2_per_uav for i in info}
    median = float(np.median(list(per_uav.values())))
    fig, panels = _paired_panels(table, metrics, 4.0)
    for ax, baseline, metric, rows, d, lo, hi in panels:
        x = np.array([per_uav[r.mission] for r in rows])
        ax.errorbar(
            x, d, yerr=[d - lo, hi - d], fmt="o", markersize=3, color=COLOURS.get(baseline), capsize=2
        )
        ax.axhline(0.0, color="black", linestyle="--")
        ax.axvline(median, color="tab:grey", linestyle=":", label=f"median {median:.3g} km$^2$ per UAV")
        ax.set_xscale("log")
        ax.set_xlabel("region area per UAV (km$^2$)")
        ax.set_ylabel(f"{metric}: proposed - {baseline}")
        ax.legend(loc="lower left", fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_study(path: Path, history: Sequence[Trial], title: str) -> None:
    """`uavsearch tune`: each trial's objective and the best so far, and its trade-off of metrics.

    The trade-off is each trial's relative change of the mean target time against that of the mean
    uncertainty (trial 0, the weights before, at 0).
    """
    trials = np.array([h.trial for h in history])
    objective = np.array([h.objective for h in history])
    time = 100 * np.array([h.relative_target_time for h in history])
    unc = 100 * np.array([h.relative_uncertainty for h in history])
    best = int(np.argmin(objective))
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.8))
    a.plot(trials, objective, "o", markersize=3, color="tab:grey", label="trial")
    a.step(trials, np.minimum.accumulate(objective), where="post", color="tab:red", label="best so far")
    a.axhline(0.0, color="black", linestyle="--", linewidth=0.8)
    a.set_xlabel("trial")
    a.set_ylabel("objective J (relative to trial 0; lower is better)")
    a.set_title(f"{title}: {len(history)} trials")
    a.legend()
    points = b.scatter(unc, time, c=trials, cmap="viridis", s=12)
    b.plot(unc[best], time[best], "*", color="tab:red", markersize=14, label=f"best (trial {trials[best]})")
    b.plot(0, 0, "s", color="black", label="trial 0 (weights before)")
    b.axhline(0.0, color="black", linewidth=0.5)
    b.axvline(0.0, color="black", linewidth=0.5)
    b.set_xlabel("mean uncertainty over the run: change (%)")
    b.set_ylabel("mean target time: change (%)")
    b.legend()
    fig.colorbar(points, ax=b, label="trial")
    for ax in (a, b):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
