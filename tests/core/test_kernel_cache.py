"""numba's disk cache of a kernel follows the kernels it calls from other modules (kernel_cache)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

from companion.core.kernel_cache import dependency_digest

REPO = Path(__file__).resolve().parents[2]


def _package(tmp: Path, name: str, installed: bool) -> Path:
    """A package whose kernel `twice` calls the kernel `inc` of another of its modules."""
    root = tmp / name
    root.mkdir()
    init = "from pathlib import Path\nfrom companion.core.kernel_cache import install\n"
    init += f"install(Path(__file__).parent, {name!r})\n"
    (root / "__init__.py").write_text(init if installed else "")
    (root / "inner.py").write_text("from numba import njit\n\n@njit(cache=True)\ndef inc():\n    return 1\n")
    (root / "outer.py").write_text(
        textwrap.dedent(f"""\
            from numba import njit
            from {name}.inner import inc

            @njit(cache=True)
            def twice():
                return 2 * inc()
            """)
    )
    return root


def _twice(tmp: Path, name: str) -> int:
    """`twice()` in a fresh process, with numba's cache in tmp/cache."""
    env = {**os.environ, "PYTHONPATH": f"{tmp}{os.pathsep}{REPO}", "NUMBA_CACHE_DIR": str(tmp / "cache")}
    done = subprocess.run(
        [sys.executable, "-c", f"from {name}.outer import twice; print(twice())"],
        cwd=tmp,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    return int(done.stdout.strip())


def test_an_edited_callee_recompiles_its_callers(tmp_path: Path) -> None:
    """After `inc` changes, `twice` is compiled again; numba's own stamp keeps the stale one."""
    stamped, plain = _package(tmp_path, "stamped", True), _package(tmp_path, "plain", False)
    assert _twice(tmp_path, "stamped") == 2 and _twice(tmp_path, "plain") == 2  # both cached now
    for root in (stamped, plain):
        (root / "inner.py").write_text((root / "inner.py").read_text().replace("return 1", "return 5"))
    assert _twice(tmp_path, "stamped") == 10
    assert _twice(tmp_path, "plain") == 2  # numba issue #1833: why kernel_cache exists


def test_the_digest_covers_transitive_imports_only(tmp_path: Path) -> None:
    """A module's digest changes with what it imports, directly or not, and with nothing else."""
    root = tmp_path / "pkg"
    (root / "sub").mkdir(parents=True)
    (root / "__init__.py").write_text("")
    (root / "sub" / "__init__.py").write_text("")
    (root / "a.py").write_text("from pkg.sub import b\n")
    (root / "sub" / "b.py").write_text("from . import c\n")
    (root / "sub" / "c.py").write_text("X = 1\n")
    (root / "d.py").write_text("Y = 1\n")

    def digest() -> bytes:
        dependency_digest.cache_clear()
        return dependency_digest(root / "a.py", root, "pkg")

    before = digest()
    (root / "d.py").write_text("Y = 2\n")
    assert digest() == before
    (root / "sub" / "c.py").write_text("X = 2\n")
    assert digest() != before
