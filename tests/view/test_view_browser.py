"""The view in a real headless Chromium against a real flying swarm, then its replay.

One lockstep `uavsearch run --view` of scenario 1's four UAVs on loopback, watched by a second,
standalone `uavsearch view --mission`. The test holds the mission's seed endpoint with its own
Zenoh peer (the companions and the views join through it, as through any first peer) and puts
malformed bundles on the mesh before and during the flight. Checks: both pages load and show the
four UAVs; between two screenshots their drawn positions move and match the companions' logs
within a cell (and the UAV's colour is on the canvas where the page says it drew it); a page
that leaves and a client that drops its connection mid-flight break nothing; the found-target
counter and eq. 30 end where the run's own files do; and the replay's slider shows the state of
a chosen step. A short replay of the no-fly example shows each zone filled and labelled and its
keep-out dashed. Set UAVSEARCH_VIEW_SHOTS=DIR to keep the screenshots (docs/view.md's come so).
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import socket
import struct
import sys
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path

import numpy as np
import zenoh
from PIL import Image
from playwright.sync_api import BrowserContext, Page
from shapely.geometry import LineString, Point, Polygon

from companion.app.view.scene import build_scene
from companion.batch.experiments import compare
from companion.contracts.zenoh_config import peer_config
from companion.core.feasibility import load_mission
from companion.core.world import build_world
from companion.node.mesh import Bundle, encode_bundle, key_base
from tests.e2e.conftest import PY, STARTUP_S, MissionFile, Proc, Procs
from tests.view.conftest import nofly_mission

STEPS = 300
REPLAY_STEP = 150
COLOURS = ["#2563eb", "#dc2626", "#059669", "#d97706"]  # app.js's first four UAV colours
WAIT_MS = 1000 * STARTUP_S


def _view(procs: Procs, name: str, *args: str) -> tuple[Proc, str]:
    proc = procs.start(name, [PY, "-m", "companion.cli", "view", *args, "--port", "0"])
    proc.wait_for_text("view at ")
    return proc, proc.text().split("view at ", 1)[1].split()[0]


def _url_after(proc: Proc, text: str) -> str:
    proc.wait_for_text(text)
    return proc.text().split(text, 1)[1].split()[0]


ROWS = "() => [...document.querySelectorAll('#uavs tbody tr')].map(tr => ({...tr.dataset}))"


def _frozen(page: Page, shot: Path) -> tuple[list[dict[str, str]], dict]:
    """Stop following the live mesh, let the page draw, screenshot it; the UAV table's rows and
    where the map's world-to-screen transform puts (x, y): screen (left + ox + s x, top + oy - s y)."""
    page.locator("#follow").uncheck()
    page.evaluate("() => new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
    page.screenshot(path=str(shot))
    rows = page.evaluate(ROWS)
    box = page.locator("#map").bounding_box()
    ds = page.evaluate("() => ({...document.getElementById('map').dataset})")
    page.locator("#follow").check()
    left, top = box["x"] + float(ds["ox"]), box["y"] + float(ds["oy"])
    return rows, {"left": left, "top": top, "s": float(ds["scale"]), "box": box}


def _log(out: Path, uav: int) -> dict[int, dict[str, str]]:
    with (out / f"uav{uav}.csv").open() as f:
        return {int(r["step"]): r for r in csv.DictReader(f)}


def _colour_at(shot: Path, screen: dict, x: float, y: float) -> tuple[int, ...]:
    """The screenshot's colour where the map draws the world point (x, y)."""
    with Image.open(shot) as img:
        return img.convert("RGB").getpixel(
            (round(screen["left"] + screen["s"] * x), round(screen["top"] - screen["s"] * y))
        )


def _hex(c: str) -> tuple[int, int, int]:
    return int(c[1:3], 16), int(c[3:5], 16), int(c[5:7], 16)


def _put_junk(session: zenoh.Session, base: str) -> int:
    """Malformed bundles on UAV 1's key: not msgpack, a wrong shape, an unknown sender."""
    bad = Bundle(sender=7, stamp=3, x=0.0, y=0.0)
    junk = [b"\x00not msgpack", b"\x93\x01\x02\x03", encode_bundle(bad)]
    for payload in junk:
        session.put(f"{base}/uav/1/msg", payload)
    return len(junk)


def _drop_abruptly(url: str) -> None:
    """A websocket client that vanishes without a goodbye (TCP reset, no close frame)."""
    host, port = url.split("//")[1].rstrip("/").rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=10) as s:
        s.sendall(
            b"GET /ws HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
        )
        assert b"101" in s.recv(4096).split(b"\r\n", 1)[0]
        s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))


def malformed(page: Page) -> int:
    """The malformed bundles the page's server has counted."""
    return int(page.evaluate("() => Number(document.body.dataset.malformed || 0)"))


def _keep(shots: list[Path]) -> None:
    target = os.environ.get("UAVSEARCH_VIEW_SHOTS")
    if target:
        for shot in shots:
            shutil.copy(shot, Path(target) / shot.name)


def test_live_map_of_a_flying_swarm_and_its_replay(
    make_mission: Callable[..., MissionFile], procs: Procs, browser: BrowserContext, tmp_path: Path
) -> None:
    mission = make_mission(n=4, kinematics="grid")
    m = mission.mission
    base = key_base(m)
    out = tmp_path / "out"
    hub = zenoh.open(peer_config((m.mesh.seed_endpoint,), ()))  # holds the seed: the others join it
    try:
        view, url = _view(procs, "view", "--mission", str(mission.path))
        page = browser.new_page()
        page.goto(url)
        page.wait_for_selector("body[data-ready]", timeout=WAIT_MS)
        assert page.locator("#uavs tbody tr").count() == m.n_uavs
        assert page.locator("#mode").text_content() == "live"
        deadline = time.monotonic() + STARTUP_S
        while malformed(page) == 0:  # until the view's subscription is known here
            assert time.monotonic() < deadline, "the view never counted the malformed bundles"
            _put_junk(hub, base)
            time.sleep(0.5)
        before = malformed(page)

        run = procs.start(
            "run",
            [PY, "-m", "companion.cli", "run", str(mission.path), "--lockstep", "--steps", str(STEPS),
             "--keep-going", "--view", "--quiet", "--out", str(out)],
        )  # fmt: skip
        second = browser.new_page()
        second.goto(_url_after(run, "live map of the swarm: "))
        second.wait_for_selector("body[data-frames]", timeout=WAIT_MS)
        assert second.locator("#uavs tbody tr").count() == m.n_uavs

        # two moments of the flight, as drawn
        page.wait_for_function("() => Number(document.body.dataset.step) >= 20", timeout=WAIT_MS)
        shot_a, shot_b = tmp_path / "view-live-a.png", tmp_path / "view-live.png"
        rows_a, screen_a = _frozen(page, shot_a)
        _put_junk(hub, base)  # mid-flight: the companions get these too
        second.close()  # a viewer leaves
        _drop_abruptly(url)  # and a client vanishes
        step_a = int(rows_a[0]["step"])
        page.wait_for_function(f"() => Number(document.body.dataset.step) >= {step_a + 10}", timeout=WAIT_MS)
        rows_b, screen_b = _frozen(page, shot_b)

        assert run.wait(STARTUP_S + 300) in (0, 1), run.text()  # 1: criteria, not the point here
    finally:
        hub.close()

    # every step flown despite the viewers and the junk
    with (out / "trajectories.csv").open() as f:
        flown = list(csv.DictReader(f))
    assert len(flown) == STEPS * m.n_uavs
    logs = [_log(out, i) for i in range(m.n_uavs)]
    cell = m.region.cell_size
    x0, y0, x1, y1 = np.min(m.region.polygon, axis=0).tolist() + np.max(m.region.polygon, axis=0).tolist()
    for shot, rows, screen in ((shot_a, rows_a, screen_a), (shot_b, rows_b, screen_b)):
        box, s = screen["box"], screen["s"]
        for x, y in ((x0, y0), (x1, y1)):  # the region's corners fall inside the map's canvas
            px, py = screen["left"] + s * x, screen["top"] - s * y
            assert box["x"] <= px <= box["x"] + box["width"] and box["y"] <= py <= box["y"] + box["height"]
        assert s * (x1 - x0) > 0.5 * min(box["width"], box["height"]), "the region fills the map"
        for i, row in enumerate(rows):
            logged = logs[i][int(row["step"])]
            x, y = float(logged["x"]), float(logged["y"])
            assert abs(float(row["x"]) - x) <= cell and abs(float(row["y"]) - y) <= cell, (
                f"uav {i} off its log"
            )
            assert row["silent"] == "0"
            # on the map, where its row says, even out in the operating margin (the map shows the fence)
            px, py = screen["left"] + s * float(row["x"]), screen["top"] - s * float(row["y"])
            assert box["x"] <= px <= box["x"] + box["width"] and box["y"] <= py <= box["y"] + box["height"]
            seen = _colour_at(shot, screen, float(row["x"]), float(row["y"]))
            assert all(abs(a - b) <= 40 for a, b in zip(seen, _hex(COLOURS[i]), strict=True)), (
                f"uav {i}: {seen} where its row puts it on the map ({row}; logged {x}, {y}), not its "
                f"colour {COLOURS[i]}"
            )
    for i, (a, b) in enumerate(zip(rows_a, rows_b, strict=True)):
        # it flew in between (a loiter may bring it back to the same cell: 8 steps a lap in grid mode)
        steps = range(int(a["step"]), int(b["step"]) + 1)
        cells = {(logs[i][k]["x"], logs[i][k]["y"]) for k in steps}
        assert len(cells) > 1, f"uav {i} did not move between the screenshots"
    with Image.open(shot_a) as a, Image.open(shot_b) as b:
        assert np.count_nonzero(np.asarray(a.convert("RGB")) != np.asarray(b.convert("RGB"))) > 0

    # the end of the flight, on the page that watched it all
    last = max(logs[0])
    page.wait_for_function(f"() => Number(document.body.dataset.step) === {last}", timeout=WAIT_MS)
    with (out / "targets.csv").open() as f:
        found = [int(r["found_step"]) for r in csv.DictReader(f)]
    assert page.locator("#found-count").text_content() == str(sum(s >= 0 for s in found))
    assert sum(s >= 0 for s in found) > 0
    assert page.locator("#found-list li").count() == sum(s >= 0 for s in found)
    eq30 = page.evaluate("() => window.uavView.frames[window.uavView.cur].m[1]")
    logged_eq30 = np.mean([float(log[last]["mean_eta"]) for log in logs])
    assert abs(eq30 - logged_eq30) <= 2e-6, "eq. 30 from the mesh, as the companions' own maps give it"
    assert malformed(page) > before  # the mid-flight junk too (a loaded viewer may drop some of it)
    page.wait_for_function(  # the companions have gone: their tokens too
        "() => [...document.querySelectorAll('#uavs tbody tr')].every(tr => tr.dataset.silent === '1')",
        timeout=WAIT_MS,
    )
    with urllib.request.urlopen(url + "api/status", timeout=10) as r:
        assert json.load(r)["connected"] is True
    assert view.stop() == 0  # SIGINT: a clean exit

    # the replay of the run's output, at a chosen step
    replay, replay_url = _view(procs, "replay", "--replay", str(out))
    page = browser.new_page()
    page.goto(replay_url)
    page.wait_for_function(f"() => Number(document.body.dataset.frames) === {STEPS}", timeout=WAIT_MS)
    assert page.locator("#mode").text_content() == "replay"
    page.locator("#slider").fill(str(REPLAY_STEP))
    page.wait_for_function(f"() => Number(document.body.dataset.step) === {REPLAY_STEP}", timeout=WAIT_MS)
    rows = page.evaluate(ROWS)
    at = {int(r["uav"]): r for r in flown if int(r["step"]) == REPLAY_STEP}
    for i, row in enumerate(rows):
        assert (
            abs(float(row["x"]) - float(at[i]["x"])) < 1e-3
            and abs(float(row["y"]) - float(at[i]["y"])) < 1e-3
        )
        assert int(row["task"]) == int(at[i]["task"])
    assert page.locator("#found-count").text_content() == str(sum(0 <= s <= REPLAY_STEP for s in found))
    with (out / "steps.csv").open() as f:
        figures = {int(r["step"]): r for r in csv.DictReader(f)}
    assert page.locator("#uncertainty").text_content() == f"{float(figures[REPLAY_STEP]['uncertainty']):.4f}"
    shot = tmp_path / "view-replay.png"
    page.screenshot(path=str(shot))
    page.locator("#play").click()
    page.wait_for_function(f"() => Number(document.body.dataset.step) > {REPLAY_STEP}", timeout=WAIT_MS)
    page.locator("#play").click()
    assert replay.stop() == 0
    _keep([shot_b, shot])
    print(f"screenshots in {tmp_path}", file=sys.stderr)


NOFLY_STEPS = 3
ZONE = "#3f3f46"  # app.js's no-fly colour


def _near(
    shot: Image.Image, screen: dict, x: float, y: float, colour: tuple[int, int, int], tol: int
) -> bool:
    """Whether a pixel within one of where the map draws (x, y) has `colour` (each channel within `tol`)."""
    cx, cy = round(screen["left"] + screen["s"] * x), round(screen["top"] - screen["s"] * y)
    pixels = (shot.getpixel((cx + dx, cy + dy)) for dx in (-1, 0, 1) for dy in (-1, 0, 1))
    return any(all(abs(a - b) <= tol for a, b in zip(p, colour, strict=True)) for p in pixels)


def test_the_map_draws_each_no_fly_zone_and_its_keep_out(
    procs: Procs, browser: BrowserContext, tmp_path: Path
) -> None:
    """A short replay of the no-fly example: each zone filled and labelled, its keep-out dashed."""
    path = nofly_mission(tmp_path)
    mission = load_mission(path)
    out = tmp_path / "mc"
    compare(mission, ["proposed"], 1, NOFLY_STEPS, 1, out, workers=1, save_trajectories=True, progress=False)
    replay, url = _view(procs, "replay", "--replay", str(out), "--mission", str(path))
    page = browser.new_page()
    page.goto(url)
    page.wait_for_function(f"() => Number(document.body.dataset.frames) === {NOFLY_STEPS}", timeout=WAIT_MS)
    page.evaluate("() => new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
    shot = tmp_path / "view-nofly.png"
    page.screenshot(path=str(shot))
    box = page.locator("#map").bounding_box()
    ds = page.evaluate("() => ({...document.getElementById('map').dataset})")
    screen = {"left": box["x"] + float(ds["ox"]), "top": box["y"] + float(ds["oy"]), "s": float(ds["scale"])}
    scene = build_scene(build_world(mission, 1, 0), "replay", 1)
    assert len(scene.nofly) == 2
    with Image.open(shot) as img:
        rgb = img.convert("RGB")
        for zone in scene.nofly:
            # filled: the zone's inside (away from its edge and its label) in the zone's colour
            inner, label = Polygon(zone.ring).buffer(-30.0), Point(zone.at).buffer(80.0)
            x0, y0, x1, y1 = inner.bounds
            inside = [
                (x, y)
                for x in np.linspace(x0, x1, 25)
                for y in np.linspace(y0, y1, 25)
                if inner.contains(Point(x, y)) and not label.contains(Point(x, y))
            ]
            filled = sum(_near(rgb, screen, x, y, _hex(ZONE), 12) for x, y in inside)
            assert inside and filled >= 0.8 * len(inside), f"{zone.label}: {filled}/{len(inside)} filled"
            # labelled: white text on the fill where the label goes
            lx, ly = screen["left"] + screen["s"] * zone.at[0], screen["top"] - screen["s"] * zone.at[1]
            text = np.asarray(rgb.crop((round(lx) - 40, round(ly) - 7, round(lx) + 40, round(ly) + 7)))
            assert np.count_nonzero(text.min(axis=2) >= 245) >= 10, f"{zone.label}: no label drawn"
            # the keep-out: the zone grown by the margin, a dashed outline (six on, four off)
            ring = LineString([*zone.inflated[0], zone.inflated[0][0]])
            along = [ring.interpolate(d) for d in np.arange(0.0, ring.length, 4.0 / screen["s"])]
            dashed = sum(_near(rgb, screen, p.x, p.y, _hex(ZONE), 30) for p in along)
            assert 0.4 * len(along) <= dashed < len(along), (
                f"{zone.label}: {dashed}/{len(along)} on its keep-out"
            )
    assert replay.stop() == 0
    _keep([shot])
