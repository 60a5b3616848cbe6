"""numba's disk cache keyed on what a kernel compiles in (graphsvc/kernel_cache.py)."""

import os
import subprocess
import sys
import textwrap

from graphsvc import kernel_cache


def _write(root, files):
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))


def test_dependencies_follow_imports_through_numba_modules_only(tmp_path):
    pkg = tmp_path / "pkg"
    _write(
        pkg,
        {
            "__init__.py": "",
            "a.py": "import numba\nfrom pkg.b import f\nfrom pkg import c\nimport os\n",
            "b.py": "import numba\nfrom . import d\n\ndef f():\n    from pkg.sub.g import h\n",
            "c.py": "from pkg.e import E  # constants, no kernels\n",
            "d.py": "D = 1\n",
            "e.py": "E = 2\n",
            "sub/__init__.py": "",
            "sub/g.py": "h = 3\n",
        },
    )
    got = {p.relative_to(pkg).as_posix() for p in kernel_cache.dependencies(pkg / "a.py", pkg)}
    # b uses numba: its imports (relative, and inside a function) count; c does not: e is not followed
    assert got == {"__init__.py", "a.py", "b.py", "c.py", "d.py", "sub/g.py"}  # (`from pkg import c` names pkg too)


def test_a_cached_kernel_recompiles_when_a_module_it_imports_changes(tmp_path):
    # numba alone stamps a cached kernel with its own file: after the constant it reads
    # from another module changed, a later process would load the old machine code.
    _write(
        tmp_path / "pkg",
        {
            "__init__.py": "",
            "consts.py": "SCALE = 2.0\n",
            "kern.py": """
            import numba
            from pkg.consts import SCALE

            @numba.njit(cache=True)
            def scaled(x):
                return x * SCALE
            """,
            "other.py": "UNRELATED = 1\n",
        },
    )
    code = (
        "import sys\n"
        "from graphsvc import kernel_cache\n"
        f"kernel_cache.cover({str(tmp_path / 'pkg')!r})\n"
        f"sys.path.insert(0, {str(tmp_path)!r})\n"
        "from pkg.kern import scaled\n"
        "print(scaled(1.0), sum(scaled.stats.cache_hits.values()))\n"
    )
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}

    def run():
        done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
        value, hits = done.stdout.split()
        return float(value), int(hits)

    assert run() == (2.0, 0)  # compiled and cached
    assert run() == (2.0, 1)  # loaded from the cache
    (tmp_path / "pkg" / "other.py").write_text("UNRELATED = 22\n")
    assert run() == (2.0, 1)  # a module the kernel does not import: the cache stays
    (tmp_path / "pkg" / "consts.py").write_text("SCALE = 3.0\n")
    assert run() == (3.0, 0)  # recompiled, not served the old code
    assert run() == (3.0, 1)


def test_the_locator_is_installed_for_the_package():
    from numba.core import caching

    # (if numba renames its hook, this fails: caching would silently fall back to per-file stamps)
    assert kernel_cache.install()
    impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl
    assert impl._locator_classes[0].__name__ == "PackageLocator"
