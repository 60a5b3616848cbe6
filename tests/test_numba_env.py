"""The package's OpenMP wait setting (graphsvc/numba_env.py)."""

from graphsvc import numba_env


def test_spin_count_is_set_unless_the_user_chose(monkeypatch):
    monkeypatch.delenv("GOMP_SPINCOUNT", raising=False)
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    numba_env.configure()
    import os

    assert os.environ["GOMP_SPINCOUNT"] == numba_env.SPIN_COUNT
    monkeypatch.setenv("GOMP_SPINCOUNT", "7")
    numba_env.configure()
    assert os.environ["GOMP_SPINCOUNT"] == "7"
    monkeypatch.delenv("GOMP_SPINCOUNT")
    monkeypatch.setenv("OMP_WAIT_POLICY", "PASSIVE")
    numba_env.configure()
    assert "GOMP_SPINCOUNT" not in os.environ


def test_blas_thread_timeout_is_set_unless_the_user_chose(monkeypatch):
    import os

    monkeypatch.delenv("OPENBLAS_THREAD_TIMEOUT", raising=False)
    numba_env.configure()
    assert os.environ["OPENBLAS_THREAD_TIMEOUT"] == numba_env.BLAS_TIMEOUT
    monkeypatch.setenv("OPENBLAS_THREAD_TIMEOUT", "12")
    numba_env.configure()
    assert os.environ["OPENBLAS_THREAD_TIMEOUT"] == "12"


def test_the_package_sets_them_before_numpy_loads():
    """In a fresh interpreter, importing graphsvc first leaves the settings for OpenBLAS
    to read when numpy loads it."""
    import subprocess
    import sys

    code = (
        "import os, sys\n"
        "seen = {}\n"
        "class Hook:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'numpy' and not seen:\n"
        "            seen['at numpy'] = (os.environ.get('OPENBLAS_THREAD_TIMEOUT'), os.environ.get('GOMP_SPINCOUNT'))\n"
        "sys.meta_path.insert(0, Hook())\n"
        "import graphsvc\n"
        "print(*seen['at numpy'])\n"
    )
    env = {
        k: v
        for k, v in __import__("os").environ.items()
        if k not in ("OPENBLAS_THREAD_TIMEOUT", "GOMP_SPINCOUNT", "OMP_WAIT_POLICY")
    }
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True).stdout
    assert out.split() == [numba_env.BLAS_TIMEOUT, numba_env.SPIN_COUNT]
