"""numba's disk cache, keyed on everything a kernel compiles in, not on its file alone.

numba (`cache=True`) stamps a cached kernel with a hash of the source file that defines
it. A kernel that calls kernels or reads constants from other modules (the Viterbi
passes call the cost terms in `strategies/viterbi/costs.py` and the intrinsics in
`intrinsics.py`; synthesis and the bridges share `motion/placement.py`) would then be
served its old machine code after one of those files changed: a changed cost term
would silently not apply until the caches were emptied by hand.

`install()` puts a cache locator ahead of numba's own for functions defined inside
this package: it keeps the place numba's standard locator picks (NUMBA_CACHE_DIR, the
module's `__pycache__`, or the user-wide cache) and stamps the entry with a hash of
the defining file and of every module of the package it imports, following imports
through the modules that themselves use numba (read statically, so nothing is
imported). A change anywhere a kernel could see recompiles it; a change elsewhere
keeps the cache. It relies on numba's locator hook (`CacheImpl._locator_classes`,
the extension point numba's own locators use); if a numba release drops the hook,
caching falls back to numba's per-file stamps.

Written here, not taken from a library: no package offers dependency-aware stamps for
numba's cache.
"""

from __future__ import annotations

import ast
import functools
import hashlib
from pathlib import Path

PACKAGE_ROOT = Path(__file__).resolve().parent
_ROOTS: list[Path] = [PACKAGE_ROOT]


def _module_file(name: str, top: Path) -> Path | None:
    """The file of module `name` (dotted, its first part the package at `top`), if any."""
    parts = name.split(".")
    if parts[0] != top.name:
        return None
    base = top.joinpath(*parts[1:])
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _imports(path: Path, top: Path) -> set[Path]:
    """The files of the package's modules that `path` imports (absolute or relative,
    anywhere in the file), including submodules named by `from x import y`."""
    st = path.stat()
    return _imports_of(path, st.st_mtime_ns, st.st_size, top)


@functools.cache
def _imports_of(path: Path, mtime_ns: int, size: int, top: Path) -> frozenset[Path]:
    tree = ast.parse(path.read_bytes(), str(path))
    here = ".".join((top.name, *path.relative_to(top).with_suffix("").parts))
    if path.name == "__init__.py":
        here = here.rsplit(".", 1)[0] + ".__init__"
    found: set[Path] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = here.split(".")[: -node.level]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            names = [module] + [f"{module}.{alias.name}" for alias in node.names]
        else:
            continue
        for name in names:
            f = _module_file(name, top)
            if f is not None and f != path:
                found.add(f)
    return frozenset(found)


def dependencies(path: Path, top: Path | None = None) -> list[Path]:
    """`path` and the package modules whose code or constants a kernel defined in it
    can compile in: every module it imports, and, for those that use numba, what they
    import in turn. Sorted, so the stamp does not depend on traversal order."""
    path = Path(path).resolve()
    top = _root_of(path) if top is None else Path(top).resolve()
    seen = {path}
    todo = [path]
    while todo:
        f = todo.pop()
        for g in _imports(f, top):
            if g in seen:
                continue
            seen.add(g)
            if b"numba" in g.read_bytes():
                todo.append(g)
    return sorted(seen)


def _root_of(path: Path) -> Path | None:
    for root in _ROOTS:
        if path == root or root in path.parents:
            return root
    return None


def source_stamp(path: Path) -> str:
    """A hash of the contents of `path` and its `dependencies`."""
    files = dependencies(path)
    return _digest(tuple((str(f), f.stat().st_mtime_ns, f.stat().st_size) for f in files))


@functools.cache
def _digest(files: tuple) -> str:
    h = hashlib.sha256()
    for name, _, _ in files:
        h.update(name.encode())
        h.update(b"\0")
        h.update(Path(name).read_bytes())
        h.update(b"\0")
    return h.hexdigest()


def cover(root) -> None:
    """Also stamp kernels defined under `root`, a package folder (tests use it)."""
    r = Path(root).resolve()
    if r not in _ROOTS:
        _ROOTS.append(r)


_installed = False


def install() -> bool:
    """Register the locator (once); False when numba's hook is missing."""
    global _installed
    if _installed:
        return True
    try:
        from numba.core import caching
    except ImportError:  # (numba is a dependency; without it nothing is cached anyway)
        return False
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)  # (older numba: _CacheImpl)
    classes = getattr(impl, "_locator_classes", None)
    base = getattr(caching, "_CacheLocator", None)
    if not isinstance(classes, list) or base is None:
        return False
    standard = tuple(classes)

    class PackageLocator(base):
        """numba's standard locator for the function, with the package-wide stamp."""

        def __init__(self, inner, py_file):
            self._inner = inner
            self._py_file = Path(py_file).resolve()

        def ensure_cache_path(self):
            self._inner.ensure_cache_path()

        def get_cache_path(self):
            return self._inner.get_cache_path()

        def get_source_stamp(self):
            return self._inner.get_source_stamp(), source_stamp(self._py_file)

        def get_disambiguator(self):
            return self._inner.get_disambiguator()

        @classmethod
        def from_function(cls, py_func, py_file):
            try:
                inside = _root_of(Path(py_file).resolve()) is not None
            except (OSError, ValueError):
                return None
            if not inside:
                return None
            for other in standard:
                inner = other.from_function(py_func, py_file)
                if inner is not None:
                    return cls(inner, py_file)
            return None

    classes.insert(0, PackageLocator)
    _installed = True
    return True
