"""numba's disk cache stamped with a kernel module's imports, not with its own file alone.

numba (`cache=True`) reuses a cached kernel while its own source file is unchanged, although the
kernels it calls from other modules are compiled into it (numba issue #1833): after an edit of
`safety/search_area.py`, `gathered.py`'s cached kernels went on running the old keep-out test.
`install` puts locators before numba's own that, for the files under one package's root, stamp
a cache entry with the source of its module and of every module of the package that module
imports, directly or not; a change to any of them makes numba compile the entry again and
overwrite it. Files outside the package keep numba's own locators.
"""

from __future__ import annotations

import ast
import hashlib
from collections.abc import Callable
from functools import cache
from pathlib import Path
from typing import Any

from numba.core import caching

_BASES = ("UserProvidedCacheLocator", "InTreeCacheLocator", "UserWideCacheLocator")


def _module_files(name: str, root: Path, package: str) -> list[Path]:
    """The source files of module `name` if it is `package` or inside it (root: its folder)."""
    parts = name.split(".")
    if parts[0] != package:
        return []
    base = root.joinpath(*parts[1:])
    candidates = [base / "__init__.py"] + ([base.with_suffix(".py")] if parts[1:] else [])
    return [c for c in candidates if c.is_file()]


def _imported_names(path: Path, root: Path, package: str) -> list[str]:
    """Dotted names of everything the module at `path` imports (relative imports made absolute)."""
    here = [package, *path.relative_to(root).parent.parts]
    names: list[str] = []
    for node in ast.walk(ast.parse(path.read_bytes(), filename=str(path))):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            prefix = here[: len(here) - node.level + 1] if node.level else []
            module = ".".join([*prefix, *(node.module.split(".") if node.module else [])])
            names += [module] + [f"{module}.{alias.name}" for alias in node.names]
    return names


@cache
def _imports(path: Path, root: Path, package: str) -> tuple[Path, ...]:
    """The files of `package` that the module at `path` imports directly."""
    found = {f for name in _imported_names(path, root, package) for f in _module_files(name, root, package)}
    return tuple(sorted(found))


@cache
def dependency_digest(path: Path, root: Path, package: str) -> bytes:
    """SHA-256 of the module at `path` and of every module of `package` it imports, transitively."""
    seen: set[Path] = set()
    stack = [path]
    while stack:
        current = stack.pop()
        if current not in seen:
            seen.add(current)
            stack += _imports(current, root, package)
    digest = hashlib.sha256()
    for file in sorted(seen):
        digest.update(file.relative_to(root).as_posix().encode())
        digest.update(hashlib.sha256(file.read_bytes()).digest())
    return digest.digest()


def _numba_class(name: str) -> Any:
    """numba's class `name` (0.68 and later), or its underscored name (0.60 to 0.67)."""
    found = getattr(caching, name, None) or getattr(caching, f"_{name}", None)
    if found is None:
        raise RuntimeError(f"numba {caching.__name__} has no {name}: kernel_cache needs updating")
    return found


def _locator(base: Any, root: Path, package: str) -> type:
    """A subclass of numba's locator `base` for the files under `root`, dependency-stamped."""

    class DependencyStampedLocator(base):
        """numba's locator for a file of the package, stamped with `dependency_digest`."""

        covers = (root, package)

        @classmethod
        def from_function(cls, py_func: Callable[..., Any], py_file: str) -> Any:
            """This locator for a file under `root`, else None (numba's own take it)."""
            if not Path(py_file).resolve().is_relative_to(root):
                return None
            return super().from_function(py_func, py_file)

        def get_source_stamp(self) -> tuple[object, bytes]:
            """numba's stamp of the file, and the digest of the package modules it imports."""
            return super().get_source_stamp(), dependency_digest(Path(self._py_file).resolve(), root, package)

    return DependencyStampedLocator


def install(root: Path, package: str) -> None:
    """Put dependency-stamped locators for the modules under `root` first in numba's list.

    Call it before the package's kernels are decorated (numba finds an entry's locator and
    stamp then); calling it again for the same root changes nothing."""
    root = root.resolve()
    impl = _numba_class("CacheImpl")
    present = impl._locator_classes
    if any(getattr(cls, "covers", None) == (root, package) for cls in present):
        return
    impl._locator_classes = [_locator(_numba_class(name), root, package) for name in _BASES] + present
