"""The `uavsearch` command as the tests run it: a real subprocess from the repository's root."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def uavsearch(*args: str, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    """Run `uavsearch ARGS` (`python -m companion.cli`) to completion, capturing its output."""
    return subprocess.run(
        [sys.executable, "-m", "companion.cli", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
