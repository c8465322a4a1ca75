"""Mission files: the three scenarios load; malformed files give MissionError naming file, field, reason."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from companion.contracts.mission import MissionError
from companion.core.feasibility import load_mission, parse_mission
from companion.core.search_area import region_hull
from companion.core.world import build_grid

from .conftest import MISSIONS

BASE = (MISSIONS / "scenario1.toml").read_text()


@pytest.mark.parametrize("name", ["scenario1", "scenario2", "scenario3"])
def test_scenarios_load_with_the_papers_setting(name: str) -> None:
    m = load_mission(MISSIONS / f"{name}.toml")
    assert m.n_uavs == 4
    assert [(v.x, v.y) for v in m.vehicles] == [
        (-620.0, -980.0),
        (-220.0, -980.0),
        (180.0, -980.0),
        (580.0, -980.0),
    ]
    assert all(v.heading_deg == 90.0 for v in m.vehicles)
    assert m.region.cell_size == 40.0 and m.sensor.radius == 60.0
    assert (m.comms.range, m.comms.attraction, m.comms.safety, m.comms.repulsion) == (
        1000.0,
        700.0,
        60.0,
        120.0,
    )
    assert m.prior.sigma == 250.0 and m.prior.targets == 9
    assert m.uncertainty.gamma == 0.1 and m.uncertainty.eta0 == 1.0
    assert m.algorithm.n_g == 50 and m.algorithm.horizon == 3
    assert m.kinematics.turn_limit_deg == 45.0


def bad(text: str, source: str = "bad.toml") -> MissionError:
    with pytest.raises(MissionError) as info:
        parse_mission(text, source)
    err = info.value
    assert str(err).startswith(f"{source}: ")
    assert err.source == source and err.reason
    return err


def sub(pattern: str, repl: str, count: int = 1) -> str:
    text, n = re.subn(pattern, repl, BASE, count=count, flags=re.M)
    assert n, pattern
    return text


def test_bad_toml_syntax() -> None:
    err = bad(sub(r"^sigma = 250\.0", "sigma = = 250.0"))
    assert err.field == "(syntax)" and "line" in err.reason


def test_missing_nested_field() -> None:
    err = bad(sub(r"^radius = 60\.0.*$", ""))
    assert "sensor" in str(err) and "radius" in str(err)


def test_missing_section() -> None:
    err = bad(sub(r"^\[sensor\]\nradius = 60\.0.*$", ""))
    assert "sensor" in str(err)


def test_wrong_type_at_nested_path() -> None:
    err = bad(sub(r"^x = -220\.0", 'x = "abc"'))
    assert err.field == "vehicles[1].x"
    assert "bad.toml: vehicles[1].x:" in str(err) and "float" in err.reason


def test_wrong_type_in_array_of_tables() -> None:
    err = bad(sub(r"peak = 0\.012 \}", 'peak = "high" }'))
    assert err.field == "prior.centres[0].peak"


def test_a_misspelt_choice_lists_the_valid_ones() -> None:
    err = bad(sub(r'^name = "proposed"', 'name = "propsed"'))
    assert err.field == "algorithm.name"
    assert err.reason == "Invalid enum value 'propsed' (one of 'no-ta', 'pheromone', 'proposed')"
    err = bad(sub(r'^mode = "grid"', 'mode = "gird"'))
    assert err.field == "kinematics.mode" and "(one of 'continuous', 'grid')" in err.reason


def test_value_out_of_range() -> None:
    err = bad(sub(r"^gamma = 0\.1", "gamma = 1.5"))
    assert err.field == "uncertainty.gamma"


def test_a_non_convex_polygon_is_searched() -> None:
    """A region with a notch loads; its cells are those inside it, its fence is its hull's."""
    notch = "[0.0, 0.0], [1000.0, 1000.0], [-1000.0, 1000.0]"
    notched = sub(r"\[1000\.0, 1000\.0\], \[-1000\.0, 1000\.0\]", notch)
    m = parse_mission(notched, "notched.toml")
    hull = region_hull(m)
    assert len(m.region.polygon) == 5 and len(hull.vertices) == 4 and hull.area == pytest.approx(4e6)
    x, y = build_grid(m).centres.T
    assert not np.any(x > np.abs(y) + 1.0)  # the notch: the triangle (1000, -1000), (0, 0), (1000, 1000)
    assert np.any(x > 0)


def test_a_self_crossing_star_is_refused() -> None:
    """A pentagram turns the same way at every vertex, but its ring crosses itself."""
    star = [
        (900 * math.cos(math.radians(90 + 144 * k)), 900 * math.sin(math.radians(90 + 144 * k)))
        for k in range(5)
    ]
    poly = "polygon = [" + ", ".join(f"[{x:.3f}, {y:.3f}]" for x, y in star) + "]"
    text = re.sub(r"^polygon = .*$", poly, BASE, count=1, flags=re.M)
    text = re.sub(r"^y = -980\.0", "y = 0.0", text, flags=re.M)
    text = re.sub(
        r"^x = (-620|-220|180|580)\.0", lambda mt: f"x = {int(mt.group(1)) // 10}.0", text, flags=re.M
    )
    err = bad(text)
    assert err.field == "region.polygon"


def test_comms_ranges_out_of_order() -> None:
    err = bad(sub(r"^attraction = 700\.0", "attraction = 1100.0"))
    assert err.field == "comms" and "R_c" in err.reason
    err = bad(sub(r"^repulsion = 120\.0", "repulsion = 50.0"))
    assert err.field == "comms"


def test_vehicle_outside_the_region() -> None:
    err = bad(sub(r"^y = -980\.0", "y = -1100.0"))
    assert err.field == "vehicles[0]" and "outside" in err.reason


def test_unknown_field() -> None:
    err = bad(sub(r"^peer_timeout_steps = 5", "peer_timeout_steps = 5\nfoo = 1"))
    assert err.field == "comms" and "foo" in err.reason
    err = bad("bogus = 1\n" + BASE)
    assert "bogus" in str(err)


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.toml"
    with pytest.raises(MissionError) as info:
        load_mission(path)
    assert str(path) in str(info.value) and info.value.field == "(file)"


def test_load_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "broken.toml"
    path.write_text(sub(r"^x = -220\.0", 'x = "abc"'))
    with pytest.raises(MissionError, match=re.escape(f"{path}: vehicles[1].x:")):
        load_mission(path)


def test_quoted_number_is_a_wrong_type() -> None:
    """BUG (companion/contracts/mission.py, parse_mission): `msgspec.convert(raw, Mission, strict=False)`
    coerces strings, so `x = "-220.0"` (a TOML string) or `require_connected = "false"` is accepted
    as a number / bool. TOML is typed: convert with strict=True (the three scenario files still load).
    """
    err = bad(sub(r"^x = -220\.0", 'x = "-220.0"'))
    assert err.field == "vehicles[1].x"


@pytest.mark.parametrize(
    ("pattern", "repl", "field"),
    [(r"x = -450\.0", "x = nan", "prior.centres[0].x"), (r"^sigma = 250\.0", "sigma = inf", "prior.sigma")],
)
def test_non_finite_numbers_are_rejected(pattern: str, repl: str, field: str) -> None:
    """BUG (companion/contracts/mission.py): TOML allows nan and inf. An unconstrained float (a
    centre's x) takes nan, and a `gt=0` bound lets inf through (sigma = inf), which makes the prior
    nan or all zero.
    Fix: reject non-finite floats anywhere in the mission (a check in _validate, naming the field).
    """
    err = bad(sub(pattern, repl))
    assert field in str(err)


def test_a_region_ring_repeating_a_vertex_or_without_area_is_refused() -> None:
    closed = "[1000.0, 1000.0], [-1000.0, 1000.0], [-1000.0, -1000.0]]"
    err = bad(sub(r"\[1000\.0, 1000\.0\], \[-1000\.0, 1000\.0\]\]", closed))
    assert err.field == "region.polygon" and "vertices 4 and 0 are the same point" in err.reason
    flat = "polygon = [[-1000.0, -1000.0], [0.0, -1000.0], [1000.0, -1000.0]]"
    err = bad(sub(r"^polygon = .*$", flat))
    assert err.field == "region.polygon" and "no area" in err.reason


def test_a_typed_zone_may_be_closed_but_not_cross_itself() -> None:
    ring = "[[0.0, 0.0], [200.0, 0.0], [200.0, 100.0], [0.0, 0.0]]"
    zone = f'[[region.nofly]]\ntype = "polygon"\nring = {ring}\n\n[prior]'
    m = parse_mission(sub(r"^\[prior\]", zone), "zone.toml")
    assert len(m.region.nofly) == 1
    bowtie = "[200.0, 100.0], [200.0, 0.0], [0.0, 100.0]"
    crossing = zone.replace("[200.0, 0.0], [200.0, 100.0], [0.0, 0.0]", bowtie)
    err = bad(sub(r"^\[prior\]", crossing))
    assert err.field == "region.nofly[0].ring" and "crosses itself" in err.reason
