"""Fixtures of the view's tests: a headless Chromium driven by Playwright, and the e2e suite's
missions and process tracking (real processes over loopback only)."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from playwright.sync_api import BrowserContext, sync_playwright

from tests.e2e.conftest import make_mission, procs  # noqa: F401  (fixtures)

ROOT = Path(__file__).resolve().parents[2]
SCENARIO1 = ROOT / "mission_files" / "scenario1.toml"
NOFLY = ROOT / "mission_files" / "scenario1_nofly.toml"
CHROMIUM = Path("/usr/bin/chromium")
# Chromium as root in a closed network: no sandbox, no GPU, no background connections.
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


@pytest.fixture(scope="module")
def browser() -> Iterator[BrowserContext]:
    """Debian's Chromium under Playwright (a fresh profile). Missing: a skip, or under CI a failure."""
    if not CHROMIUM.exists():
        message = f"{CHROMIUM} is missing: `make test` installs it (apt-get install chromium)"
        if os.environ.get("CI") == "true":
            pytest.fail(message)
        pytest.skip(message)
    profile = tempfile.mkdtemp(prefix="uavsearch-chromium-")
    with sync_playwright() as p:
        context = p.chromium.launch_persistent_context(
            profile,
            executable_path=str(CHROMIUM),
            args=CHROMIUM_FLAGS,
            headless=True,
            viewport={"width": 1400, "height": 900},
        )
        try:
            yield context
        finally:
            context.close()
            shutil.rmtree(profile, ignore_errors=True)


def nofly_mission(tmp_path: Path) -> Path:
    """Scenario 1 with its .plan's no-fly band and a no-fly circle typed in the file, in `tmp_path`."""
    text = NOFLY.read_text().replace('"areas/', f'"{NOFLY.parent}/areas/')
    circle = '[[region.nofly]]\ntype = "circle"\nx = 500.0\ny = -400.0\nradius = 120.0\n\n[prior]'
    path = tmp_path / "nofly.toml"
    path.write_text(text.replace("[prior]", circle, 1))
    return path
