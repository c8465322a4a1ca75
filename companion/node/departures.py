"""Which peers a companion forgets because their liveliness token vanished (docs/mesh.md, "Liveliness").

A peer whose token goes is forgotten at once, so that its task goes back to the auction without
waiting for the agent's peer timeout, and again at every step while the token stays away: the
others may still relay what they last heard of it. The token is only what this companion's own
Zenoh links report, though. A restarted companion that the mesh links to the others but not (yet)
to this one is alive all the same, and the others relay its states here (`core.relay.relay_set`).
So a departed peer counts as back, and is no longer forgotten, as soon as a state of it stamped
after its token vanished and flown under its companion's guidance (`steered`) is known here: a
dead companion cannot send one, and one that left the mesh because it cannot steer sends only
`steered=False` states.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from companion.core.messages import UavState


@dataclass(frozen=True)
class DepartureUpdate:
    """What changed at one step among the peers whose liveliness token vanished.

    The peers whose token just vanished, the peers heard of again without their token (through
    relays), and the peers to forget now.
    """

    left: tuple[int, ...] = ()
    back: tuple[int, ...] = ()
    forget: tuple[int, ...] = ()


@dataclass
class Departures:
    """The liveliness bookkeeping of one companion (its own UAV is never among `alive`)."""

    seen: set[int] = field(default_factory=set)  # every peer whose token was ever seen
    left_at: dict[int, int] = field(default_factory=dict)  # peer -> the step its token was missed
    heard_back: set[int] = field(default_factory=set)  # departed peers heard of after they left

    def update(self, step: int, alive: set[int], known: Mapping[int, UavState]) -> DepartureUpdate:
        """The step's update from the peers whose token is held now and the agent's peer states."""
        left, back, forget = [], [], []
        for uav in sorted(self.seen - alive):
            if uav not in self.left_at:
                self.left_at[uav] = step
                left.append(uav)
            state = known.get(uav)
            if state is not None and state.stamp > self.left_at[uav] and state.steered:
                if uav not in self.heard_back:
                    self.heard_back.add(uav)
                    back.append(uav)
                continue
            self.heard_back.discard(uav)
            forget.append(uav)
        for uav in alive:
            self.left_at.pop(uav, None)
            self.heard_back.discard(uav)
        self.seen |= alive
        return DepartureUpdate(tuple(left), tuple(back), tuple(forget))
