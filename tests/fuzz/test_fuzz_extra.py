"""`uavsearch fuzz` on an install without Hypothesis (a plain `pip install .`): one line naming the
extra that brings it, exit 1, no traceback."""

from __future__ import annotations

import subprocess
import sys

from tests.cli import ROOT

# The real command line in a fresh interpreter in which `import hypothesis` fails, as it does where
# only the package's own dependencies are installed.
WITHOUT_HYPOTHESIS = (
    "import sys; sys.modules['hypothesis'] = None; sys.argv = ['uavsearch', *sys.argv[1:]]; "
    "from companion.cli.entry import main; sys.exit(main())"
)


def test_fuzz_without_hypothesis_names_the_extra() -> None:
    r = subprocess.run(
        [sys.executable, "-c", WITHOUT_HYPOTHESIS, "fuzz", "--campaign", "mission", "--count", "1"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 1, r.stderr
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert "pip install 'uavsearch[fuzz]'" in lines[0]
    assert r.stdout == ""
