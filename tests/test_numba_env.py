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
