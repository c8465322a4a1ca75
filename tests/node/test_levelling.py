"""When a take-off counts as complete (`takeover.Levelling`): the companion steers only an aircraft
that has levelled off at its layer and flown on level, never one still climbing through the layers
below or about to sink as it gathers speed."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from companion.contracts.mission import ALTITUDE_KEEPING
from companion.node.takeover import LEVEL_GAIN_M, LEVEL_M, LEVEL_S, SETTLE_S, Levelling

LAYER = 140.0
DT = 0.1  # s between positions


def _hand_over(track: list[tuple[float, float]]) -> int | None:
    """The index of the first position at which `Levelling` hands over, None if none."""
    level = Levelling(LAYER)
    return next((i for i, (t, up) in enumerate(track) if level.reached(t, up)), None)


def _climb_then_hold(hold: float, seconds: float) -> list[tuple[float, float]]:
    """3 m/s up to `hold`, then level there for `seconds`."""
    climb = [(DT * i, 3.0 * DT * i) for i in range(int(hold / (3.0 * DT)) + 1)]
    t0 = climb[-1][0]
    return climb + [(t0 + DT * i, hold) for i in range(1, int(seconds / DT))]


def test_a_climb_to_the_layer_hands_over_after_settling_there() -> None:
    track = _climb_then_hold(LAYER, 60.0)
    i = _hand_over(track)
    assert i is not None
    level = next(t for t, up in track if up >= LAYER - LEVEL_M)
    assert track[i][0] - level >= SETTLE_S and track[i - 1][0] - level < SETTLE_S


def test_an_aircraft_holding_a_little_low_hands_over_once_it_stopped_gaining() -> None:
    track = _climb_then_hold(LAYER - 3.0, 60.0)  # within ALTITUDE_KEEPING, never within LEVEL_M
    i = _hand_over(track)
    assert i is not None
    entered = next(t for t, up in track if up >= LAYER - ALTITUDE_KEEPING)
    assert track[i][0] - entered >= LEVEL_S + SETTLE_S


def test_sinking_out_of_the_band_while_settling_starts_over() -> None:
    track = _climb_then_hold(LAYER, SETTLE_S / 2)
    t0 = track[-1][0]
    track += [(t0 + DT, LAYER - ALTITUDE_KEEPING - 1.0)]  # a sag below the band
    track += [(t0 + DT * (2 + i), LAYER) for i in range(int(2 * SETTLE_S / DT))]
    i = _hand_over(track)
    assert i is not None and track[i][0] - (t0 + 2 * DT) >= SETTLE_S


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(-3.0, 3.0), min_size=1, max_size=200))
def test_never_handed_over_unless_level_in_the_band(steps: list[float]) -> None:
    """Whatever the altitude does: handed over only after SETTLE_S within ALTITUDE_KEEPING of the
    layer, from a moment within LEVEL_M of it or LEVEL_S without gaining LEVEL_GAIN_M."""
    up, track = LAYER - 20.0, []
    for i, dz in enumerate(steps):
        up += dz
        track.append((0.5 * i, up))
    i = _hand_over(track)
    if i is None:
        return
    t = track[i][0]
    settled = [k for k in range(i + 1) if all(u >= LAYER - ALTITUDE_KEEPING for _, u in track[k : i + 1])]
    assert settled and t - track[settled[0]][0] >= SETTLE_S

    def levelled(k: int) -> bool:  # at track[k]: within LEVEL_M, or LEVEL_S in the band gaining little
        tk, uk = track[k]
        return uk >= LAYER - LEVEL_M or any(
            all(LAYER - ALTITUDE_KEEPING <= u <= track[j][1] + LEVEL_GAIN_M for _, u in track[j : k + 1])
            for j in range(k + 1)
            if track[j][0] <= tk - LEVEL_S
        )

    assert any(levelled(k) and t - track[k][0] >= SETTLE_S for k in settled)
