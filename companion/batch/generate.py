"""Generated missions: a family of search missions beyond the paper's three scenario files.

A mission of the family has a random convex region (3-8 vertices, 0.8-4 km across, any
orientation), 2-12 UAVs starting on one of its edges or clustered inside it (`starts.start_layout`:
separated, connected, and with a start contingency for every UAV: `mission._validate_start`), 1-6
distribution centres of eq. 1 with their own sigma, 5-20 targets, either kinematics mode, and
one altitude layer for everyone, two, or one a UAV (as many as the default band holds), and as
many no-fly zones as `Family.zones` asks (none by default).
Everything else takes the paper's values (R_A, R_c, R'_c, R_s, R'_s, eta_0, gamma, M) and the
scenario files' choices (speed, step, weights). `generate` is a pure function of (count, seed,
family): the same seed gives the same missions, file for file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tomli_w
from scipy.spatial import ConvexHull

from companion.batch.starts import start_layout
from companion.contracts.mission import Mission, MissionError
from companion.core.feasibility import parse_mission
from companion.core.geometry import ConvexPolygon

ATTEMPTS = 200  # draws per mission before giving up (a family too tight to satisfy)


@dataclass(frozen=True)
class Family:
    """The ranges a generated mission is drawn from (inclusive)."""

    uavs: tuple[int, int] = (2, 12)
    across: tuple[float, float] = (800.0, 4000.0)  # largest vertex-to-vertex distance, m
    vertices: tuple[int, int] = (3, 8)
    centres: tuple[int, int] = (1, 6)
    targets: tuple[int, int] = (5, 20)
    sigma: tuple[float, float] = (0.06, 0.2)  # each centre's sigma, as a fraction of `across`
    layouts: tuple[str, ...] = ("edge", "clustered")
    modes: tuple[str, ...] = ("grid", "continuous")
    # altitude layers ([layers] count): everyone on one, two, or one a UAV as far as the default band
    # holds (0): the clause between UAVs sharing a layer stays exercised
    layer_counts: tuple[int, ...] = (1, 2, 0)
    cell_size: float = 40.0
    steps: int = 1000
    zones: tuple[int, int] = (0, 0)  # no-fly zones per mission: circles and bars (`_zone`)


def _polygon(rng: np.random.Generator, fam: Family) -> np.ndarray:
    """A convex polygon centred near the origin, `across` wide, not a sliver (width >= 0.35 across)."""
    while True:
        n = int(rng.integers(fam.vertices[0], fam.vertices[1] + 1))
        angles = np.sort(rng.uniform(0, 2 * math.pi, n))
        gaps = np.diff(np.append(angles, angles[0] + 2 * math.pi))
        if gaps.max() >= math.pi * 0.9:
            continue
        radii = rng.uniform(0.75, 1.0, n)
        pts = np.column_stack([radii * np.cos(angles), radii * np.sin(angles)])
        hull = pts[ConvexHull(pts).vertices]
        if len(hull) < 3:
            continue
        across = rng.uniform(*fam.across)
        hull *= across / float(np.max(np.linalg.norm(hull[:, None] - hull[None], axis=-1)))
        poly = ConvexPolygon.from_vertices(hull)
        width = min(float(np.max(poly.offsets[e] - hull @ poly.normals[e])) for e in range(len(hull)))
        if width >= 0.35 * across:
            return np.round(hull, 1)


def _peaks(
    rng: np.random.Generator, cells: np.ndarray, centres: np.ndarray, sigmas: np.ndarray, targets: int
) -> np.ndarray:
    """Peaks of eq. 1 in proportion to random weights, scaled to the mission's target count.

    The scale is found by bisection so that the expected number of targets, sum_p Pr_p, is the
    mission's target count (or as near as peaks <= 1 allow).
    """
    weights = rng.uniform(0.5, 1.0, len(centres))
    shape = np.exp(-np.sum((cells[:, None, :] - centres[None]) ** 2, axis=-1) / (2 * sigmas**2))

    def expected(scale: float) -> float:
        return float(np.sum(1 - np.prod(1 - scale * weights * shape, axis=1)))

    lo, hi = 0.0, 1.0 / weights.max()
    if expected(hi) <= targets:
        return np.round(weights * hi, 6)
    for _ in range(60):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if expected(mid) < targets else (lo, mid)
    return np.round(weights * hi, 6)


def _draw(rng: np.random.Generator, fam: Family, name: str, seed: int) -> dict | None:
    """One candidate mission as a TOML-ready dict, or None when the start layout fails.

    The caller validates the mission. None means the start layout could not place every UAV.
    """
    verts = _polygon(rng, fam)
    poly = ConvexPolygon.from_vertices(verts)
    mode = str(rng.choice(fam.modes))
    n = int(rng.integers(fam.uavs[0], fam.uavs[1] + 1))
    layout = str(rng.choice(fam.layouts))
    r_c, buffer = 1000.0, 5.0
    poses = start_layout(rng, poly, n, layout, mode == "grid", fam.cell_size, r_c - buffer)
    if len(poses) < n:
        return None
    across = float(np.max(np.linalg.norm(verts[:, None] - verts[None], axis=-1)))
    k = int(rng.integers(fam.centres[0], fam.centres[1] + 1))
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    centres: list[np.ndarray] = []
    while len(centres) < k:
        c = rng.uniform(lo, hi)
        if poly.contains(c[0], c[1]):
            centres.append(c)
    sigmas = rng.uniform(*fam.sigma, k) * across
    cell = fam.cell_size
    xs = np.arange(lo[0] + cell / 2, hi[0], cell)
    ys = np.arange(lo[1] + cell / 2, hi[1], cell)
    grid = np.array([(x, y) for y in ys for x in xs])
    grid = grid[np.asarray(poly.contains(grid[:, 0], grid[:, 1]))]
    targets = min(int(rng.integers(fam.targets[0], fam.targets[1] + 1)), len(grid))
    peaks = _peaks(rng, grid, np.array(centres), sigmas, targets)
    n_g = int(np.clip(round(len(grid) / 50), 8, 120))
    layers = int(rng.choice(fam.layer_counts))  # drawn last: the rest is as without layers
    count = int(rng.integers(fam.zones[0], fam.zones[1] + 1)) if fam.zones[1] else 0  # then zones
    zones = [_zone(rng, lo, hi, across) for _ in range(count)]
    return {
        "name": name,
        "seed": seed,
        "steps": fam.steps,
        "region": {
            "polygon": verts.tolist(),
            "cell_size": cell,
            "origin": {"lat": -35.363261, "lon": 149.16523, "alt": 584.0},
            **({"nofly": zones} if zones else {}),
        },
        "prior": {
            "sigma": float(np.round(sigmas.mean(), 1)),
            "targets": targets,
            "centres": [
                {
                    "x": round(float(c[0]), 1),
                    "y": round(float(c[1]), 1),
                    "peak": float(p),
                    "sigma": round(float(sd), 1),
                }
                for c, p, sd in zip(centres, peaks, sigmas, strict=True)
            ],
        },
        "sensor": {"radius": 60.0},
        "kinematics": {"mode": mode, "speed": 20.0, "step": 2.0, "turn_limit_deg": 45.0, "altitude": 100.0},
        "comms": {"range": r_c, "attraction": 700.0, "safety": 60.0, "repulsion": 120.0},
        "safety": {"margin": 100.0, "buffer": buffer},
        "algorithm": {"name": "proposed", "n_g": n_g},
        "vehicles": [{"x": x, "y": y, "heading_deg": h} for x, y, h in poses],
        **({"layers": {"count": layers}} if layers else {}),
    }


def _zone(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray, across: float) -> dict:
    """A no-fly zone in the region's bounding box: a circle, or a bar at any angle (a band)."""
    x, y = (round(float(v), 1) for v in rng.uniform(lo, hi))
    if rng.random() < 0.5:
        return {"type": "circle", "x": x, "y": y, "radius": round(float(rng.uniform(0.03, 0.1) * across), 1)}
    half, width = rng.uniform(0.1, 0.25) * across, rng.uniform(0.02, 0.06) * across
    angle = rng.uniform(0, np.pi)
    u, v = np.array([np.cos(angle), np.sin(angle)]), np.array([-np.sin(angle), np.cos(angle)])
    signs = ((-1, -1), (1, -1), (1, 1), (-1, 1))
    corners = [np.array([x, y]) + a * half * u + b * width / 2 * v for a, b in signs]
    return {"type": "polygon", "ring": [[round(float(c[0]), 1), round(float(c[1]), 1)] for c in corners]}


def generate(count: int, seed: int, family: Family | None = None) -> list[tuple[Mission, str]]:
    """`count` valid missions of the family and their TOML text, reproducible from `seed`.

    The family defaults to `Family()`.
    """
    family = family or Family()
    out = []
    for i in range(count):
        rng = np.random.default_rng(np.random.SeedSequence(entropy=seed, spawn_key=(i,)))
        for _ in range(ATTEMPTS):
            drawn = _draw(rng, family, f"generated-{seed}-{i:03d}", seed * 1000 + i)
            if drawn is None:
                continue
            text = tomli_w.dumps(drawn)
            try:
                out.append((parse_mission(text, f"generated mission {i}"), text))
                break
            except MissionError:
                continue
        else:
            raise ValueError(
                f"no valid mission {i} of seed {seed} in {ATTEMPTS} draws: the family is too tight"
            )
    return out


def write(missions: list[tuple[Mission, str]], out: Path) -> list[Path]:
    """Write each mission as `out/<name>.toml`; returns the paths."""
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for mission, text in missions:
        path = out / f"{mission.name}.toml"
        path.write_text(
            f"# {mission.name}: written by `uavsearch generate` (companion.batch.generate)\n{text}"
        )
        paths.append(path)
    return paths
