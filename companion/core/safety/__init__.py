"""The safety layer's geometry: compatibility, proposals, and the start contingencies.

The safety layer's geometry: when two committed trajectories are compatible, which candidate
paths may be proposed, and the contingencies every UAV starts with.

Two trajectories are *compatible* when, for every time from the first step compared on (between
sampling moments too), the UAVs flying them are farther apart than `Limits.separation`, and, for
a tether (a link that must hold), closer than `Limits.link` at every sampling moment. Trajectories
end in loiters, so comparing `Reach.window` steps covers all later time. Positions between
sampling moments are compared along the chords, with the arcs' sagitta added to the distances
(`trajectory.arc_chord_deviation`). The fence is the search region with each edge pushed out by
the mission's `safety.margin` (the operating margin): every trajectory stays inside it forever.

Modules: `limits` (what compatibility means for a mission), `expansion` (trajectory rows to
positions), `separation` (compatibility, the fence, recovery), `fans` and `contingency` (the
contingency clause), `failsafe_regions` (gone UAVs' aircraft), `switch` (resolving a proposal),
`proposal` (the first candidate that may be proposed), `start` (the start contingencies).

The protocol that keeps every pair of in-force trajectories compatible is in `core.commitment`;
the invariant and its argument are in docs/algorithm.md ("Safety layer").
"""
