"""The target-probability map: Bayes' rule in log-odds, fused between UAVs without double counting.

Each cell's log-odds is L_p = logit(Pr_p) + sum over UAVs u of E_{u,p}, where Pr_p is eq. 1's prior
and E_{u,p} the sum of the log-likelihood ratios of every look UAV u made at cell p
(`sensing.look_llr`). Only u adds to E_{u,p}; the others hold a copy stamped with the step u last
looked at p, and keep the newer of two copies (a record (u, p, stamp, E) is cumulative, so the
newer includes the older). Fusing is then idempotent and independent of order and relay path,
and since every term is a multiple of 2^-20 the sums are exact: two UAVs that exchanged every
record hold the posterior that one UAV making all their looks would hold.

A cell is *confirmed* when its posterior reaches `confirm`; a *candidate* while its evidence is
positive and its posterior lies strictly between `clear` and `confirm` (one look more decides it).
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from numba import njit

from companion.core.geometry import FloatArray, IntArray
from companion.core.messages import MAX_RECORDS, CoverageMsg  # MAX_RECORDS: records one relays
from companion.core.sensing import LLR_QUANTUM, look_llr

_NO_RECORDS = np.zeros(0, dtype=np.int64)
PRIOR_FLOOR = 1e-9  # eq. 1's prior clipped to [PRIOR_FLOOR, 1 - PRIOR_FLOOR] before its logit

# one UAV's evidence records: (source, cell, stamp) triples flattened, and the cumulative values
Records = tuple[tuple[int, ...], tuple[float, ...]]


def logit(p: float) -> float:
    """log(p / (1 - p))."""
    return math.log(p / (1.0 - p))


def prior_logodds(prior: FloatArray) -> FloatArray:
    """logit of eq. 1's prior per cell, clipped and quantized (`sensing.quantized` without the cap)."""
    p = np.clip(prior, PRIOR_FLOOR, 1.0 - PRIOR_FLOOR)
    return np.round(np.log(p / (1.0 - p)) / LLR_QUANTUM) * LLR_QUANTUM


# one UAV's map as the kernels take it: log-odds L, prior log-odds L0, evidence E (UAVs x cells) and
# the stamp of each evidence record (-1: none held)
MapArrays = tuple[FloatArray, FloatArray, FloatArray, IntArray]


@njit(cache=True)
def _set(arrays: MapArrays, u: int, c: int, stamp: int, value: float) -> bool:
    """E_{u,c} <- value at `stamp`, L_c recomputed in a fixed order; whether c is or was of interest."""
    logodds, l0, evidence, stamps = arrays
    before = logodds[c] > l0[c]
    evidence[u, c] = value
    stamps[u, c] = stamp
    total = l0[c]
    for v in range(evidence.shape[0]):
        total += evidence[v, c]
    logodds[c] = total
    return before or total > l0[c]


@njit(cache=True)
def add_looks(
    arrays: MapArrays, me: int, step: int, cells: IntArray, hits: np.ndarray, at: tuple[float, float],
    centres: FloatArray, model: tuple[float, float, float, float],
) -> tuple[bool, FloatArray]:  # fmt: skip
    """UAV `me`'s looks from `at` at step `step`: E_{me,p} += `look_llr` for each cell, hit or miss.

    `hits` may be longer than `cells` (its first len(cells) entries count). Returns whether a cell
    of interest (positive evidence) changed, and E_{me,p} after the looks at each of `cells`."""
    pd, pd_edge, pf, radius = model
    evidence = arrays[2]
    interest = False
    for i in range(cells.shape[0]):
        c = cells[i]
        d = math.hypot(centres[c, 0] - at[0], centres[c, 1] - at[1])
        llr = look_llr(hits[i], d, pd, pd_edge, pf, radius)
        interest |= _set(arrays, me, c, step, evidence[me, c] + llr)
    values = np.empty(cells.shape[0])
    for i in range(cells.shape[0]):
        values[i] = evidence[me, cells[i]]
    return interest, values


@njit(cache=True)
def merge_records(
    arrays: MapArrays, me: int, records: IntArray, values: FloatArray
) -> tuple[np.ndarray, bool]:
    """Keep each record (source, cell, stamp: a row of `records`) newer than the copy held.

    Returns which were kept and whether a cell of interest changed. Records of `me`'s own
    evidence are ignored (only it adds to them); `me` = -1 takes all."""
    stamps = arrays[3]
    taken = np.zeros(values.shape[0], dtype=np.bool_)
    interest = False
    for i in range(values.shape[0]):
        u, c, s = records[i, 0], records[i, 1], records[i, 2]
        if u != me and s > stamps[u, c]:
            interest |= _set(arrays, u, c, s, round(values[i] / LLR_QUANTUM) * LLR_QUANTUM)
            taken[i] = True
    return taken, interest


@njit(cache=True)
def heard_records(looks: IntArray, segments: IntArray, relayed: IntArray) -> IntArray:
    """The (source, cell, stamp) rows that `segments` describe, in their order.

    A segment (source, stamp, start, count) with source >= 0 stands for the cells
    looks[start:start+count], each looked at by `source` at `stamp`; one with source -1 for the
    triples relayed[3 start:3 (start+count)]."""
    n = 0
    for s in range(segments.shape[0]):
        n += segments[s, 3]
    out = np.empty((n, 3), dtype=np.int64)
    i = 0
    for s in range(segments.shape[0]):
        source, stamp, start, count = segments[s, 0], segments[s, 1], segments[s, 2], segments[s, 3]
        for j in range(start, start + count):
            if source >= 0:
                out[i, 0], out[i, 1], out[i, 2] = source, looks[j], stamp
            else:
                out[i, 0], out[i, 1], out[i, 2] = relayed[3 * j], relayed[3 * j + 1], relayed[3 * j + 2]
            i += 1
    return out


@njit(cache=True)
def merge_heard(
    arrays: MapArrays, me: int, looks: IntArray, segments: IntArray, relayed: IntArray, values: FloatArray
) -> tuple[IntArray, np.ndarray, bool]:
    """`merge_records` of the rows of `heard_records`; returns them, which were kept, and the interest."""
    records = heard_records(looks, segments, relayed)
    taken, interest = merge_records(arrays, me, records, values)
    return records, taken, interest


@njit(cache=True)
def interest_cells(logodds: FloatArray, l0: FloatArray, clear_logodds: float) -> IntArray:
    """Cells whose evidence is positive and whose posterior is above the clearing floor."""
    out = np.empty(logodds.shape[0], dtype=np.int64)
    n = 0
    for c in range(logodds.shape[0]):
        if logodds[c] > l0[c] and logodds[c] > clear_logodds:
            out[n] = c
            n += 1
    return out[:n]


@njit(cache=True)
def held_records(arrays: MapArrays, clear_logodds: float, limit: int) -> tuple[IntArray, FloatArray]:
    """The first `limit` records held at the cells of interest, by source then cell: triples, values."""
    logodds, l0, evidence, stamps = arrays
    cells = interest_cells(logodds, l0, clear_logodds)
    triples = np.empty(3 * limit, dtype=np.int64)
    values = np.empty(limit)
    n = 0
    for u in range(stamps.shape[0]):
        for c in cells:
            if stamps[u, c] >= 0 and n < limit:
                triples[3 * n], triples[3 * n + 1], triples[3 * n + 2] = u, c, stamps[u, c]
                values[n] = evidence[u, c]
                n += 1
    return triples[: 3 * n], values[:n]


@njit(cache=True)
def decided_cells(
    logodds: FloatArray, l0: FloatArray, clear_logodds: float, confirm_logodds: float
) -> tuple[IntArray, IntArray]:
    """The candidate cells and the confirmed ones, ascending (`Belief.candidates`, `Belief.confirmed`)."""
    cells = interest_cells(logodds, l0, clear_logodds)
    candidates = np.empty(cells.shape[0], dtype=np.int64)
    n = 0
    for c in cells:
        if logodds[c] < confirm_logodds:
            candidates[n] = c
            n += 1
    return candidates[:n], np.flatnonzero(logodds >= confirm_logodds)


class Belief:
    """One UAV's target-probability map (log-odds) and the evidence records it fuses."""

    def __init__(self, prior: FloatArray, n_uavs: int, me: int, confirm: float, clear: float) -> None:
        self.me = me
        self.l0 = prior_logodds(prior)
        n = self.l0.shape[0]
        self.evidence = np.zeros((n_uavs, n))
        self.stamps = np.full((n_uavs, n), -1, dtype=np.int64)
        self.logodds = self.l0.copy()
        self.confirm_logodds, self.clear_logodds = logit(confirm), logit(clear)
        self.version = 0  # changes whenever a cell of interest (positive evidence) changed
        self._records: tuple[int, Records] = (-1, ((), ()))
        self._arrays: MapArrays = (self.logodds, self.l0, self.evidence, self.stamps)  # updated in place

    # -- evidence ------------------------------------------------------------------------------
    @property
    def arrays(self) -> MapArrays:
        return self._arrays

    def look(
        self, step: int, cells: IntArray, hits: np.ndarray, at: tuple[float, float], centres: FloatArray,
        model: tuple[float, float, float, float],
    ) -> FloatArray:  # fmt: skip
        """This UAV's looks at `cells` from `at` at step `step`, a hit where `hits`; its evidence there after.

        `hits` may be longer than `cells` (its first len(cells) entries count)."""
        interest, values = add_looks(self.arrays, self.me, step, cells, hits, at, centres, model)
        self.version += interest
        return values

    def merge(self, records: IntArray, values: FloatArray, own: bool = False) -> np.ndarray:
        """Records, a (source, cell, stamp) row each, and their values (rounded to the quantum).

        Returns which records were kept (newer than the copies held). Records of this UAV's own
        evidence are skipped unless `own` (a journal's replay)."""
        taken, interest = merge_records(self.arrays, -1 if own else self.me, records, values)
        self.version += interest
        return taken

    def merge_heard(
        self, looks: IntArray, segments: IntArray, relayed: IntArray, values: FloatArray
    ) -> tuple[IntArray, np.ndarray]:
        """`merge` of the records `segments` describes (`heard_records`); returns them and which were kept."""
        records, taken, interest = merge_heard(self.arrays, self.me, looks, segments, relayed, values)
        self.version += interest
        return records, taken

    def merge_coverage(
        self,
        looks: IntArray,
        start: int,
        coverage: Iterable[CoverageMsg],
        relayed: dict[int, tuple[int, ...]],
    ) -> tuple[IntArray, FloatArray, np.ndarray] | None:
        """The neighbours' evidence and records of `coverage`, merged; None if it holds none.

        `looks[start:]` holds the cells of each message, in order (`CoverageMsg.cells`). A message's
        records are read only when they differ from `relayed[sender]`, those last read (updated).
        Returns the records, a (source, cell, stamp) row each, their values and which were kept."""
        segments: list[int] = []  # (source, stamp, start, count) each: `heard_records`
        triples: list[int] = []
        heard: list[float] = []
        for msg in coverage:
            n = len(msg.cells)
            if msg.evidence:
                segments += (msg.sender, msg.stamp, start, n)
                heard += msg.evidence
            start += n
            held = relayed.get(msg.sender)
            if msg.record_values and held is not msg.records and held != msg.records:
                relayed[msg.sender] = msg.records
                segments += (-1, 0, len(triples) // 3, len(msg.record_values))
                triples += msg.records
                heard += msg.record_values
        if not heard:
            return None
        values = np.array(heard, dtype=float)
        rows = np.array(triples, dtype=np.int64) if triples else _NO_RECORDS
        segs = np.array(segments, dtype=np.int64).reshape(-1, 4)
        records, taken = self.merge_heard(looks, segs, rows, values)
        return records, values, taken

    def records(self) -> Records:
        """Every record held at the cells of interest (confirmed or candidate), for relaying."""
        version, cached = self._records
        if version == self.version:
            return cached
        triples, values = held_records(self._arrays, self.clear_logodds, MAX_RECORDS)
        out = (tuple(triples.tolist()), tuple(values.tolist()))
        self._records = (self.version, out)
        return out

    # -- what it says ----------------------------------------------------------------------------
    def posterior(self, cells: IntArray | None = None) -> FloatArray:
        """P(target in cell | every look fused) for `cells` (all cells by default).

        A cell cleared by hundreds of misses has log-odds below -709, where exp overflows to inf
        and the posterior is exactly 0: numpy's warning about it is silenced."""
        lo = self.logodds if cells is None else self.logodds[cells]
        with np.errstate(over="ignore"):
            return 1.0 / (1.0 + np.exp(-lo))

    def confirmed(self) -> IntArray:
        """Cells whose posterior reaches the confirmation threshold."""
        return np.flatnonzero(self.logodds >= self.confirm_logodds)

    def candidates(self) -> IntArray:
        """Cells a detection left between the clearing floor and the threshold."""
        return self.decided()[0]

    def decided(self) -> tuple[IntArray, IntArray]:
        """`candidates()` and `confirmed()` in one pass."""
        return decided_cells(self.logodds, self.l0, self.clear_logodds, self.confirm_logodds)

    # -- snapshot ------------------------------------------------------------------------------
    def to_bytes(self) -> tuple[bytes, bytes]:
        """The evidence and its stamps (little-endian), for `AgentSnapshot`."""
        return self.evidence.astype("<f8").tobytes(), self.stamps.astype("<i8").tobytes()

    def restore(self, evidence: bytes, stamps: bytes) -> None:
        """Take back `to_bytes`'s evidence; raises ValueError if it does not fit."""
        if len(evidence) != self.evidence.nbytes or len(stamps) != self.stamps.nbytes:
            raise ValueError("belief of another mission")
        self.evidence[:] = np.frombuffer(evidence, dtype="<f8").reshape(self.evidence.shape)
        self.stamps[:] = np.frombuffer(stamps, dtype="<i8").reshape(self.stamps.shape)
        self.logodds[:] = self.l0 + self.evidence.sum(axis=0)
        self.version += 1
