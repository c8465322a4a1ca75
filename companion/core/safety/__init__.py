"""The safety layer's geometry: compatibility, proposals, and the start contingencies.

Two trajectories are *compatible* when the UAVs flying them stay farther apart than
`Limits.separation` at every time (chords between sampling moments, plus the arcs' sagitta) and a
tether stays within `Limits.link` at every sampling moment; trajectories end in loiters inside the
fence (the region pushed out by `safety.margin`), so `Reach.window` steps cover all later time.
Modules: `limits`, `expansion` (rows to positions), `separation` (compatibility, the fence,
recovery), `fans` and `contingency` (the contingency clause), `failsafe_regions` (gone UAVs'
aircraft), `switch` (resolving a proposal), `proposal` (the first candidate that may be
proposed), `start` (the start contingencies). The protocol is `core.commitment`; the invariant
and its argument are in docs/algorithm.md ("Safety layer").
"""
