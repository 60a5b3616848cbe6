"""graphsvc: full-body human motion from sparse measurements by searching motion capture."""

from graphsvc import numba_env as _numba_env

_numba_env.configure()  # before numpy loads OpenBLAS and numba starts its threads (graphsvc/numba_env.py)

from graphsvc import kernel_cache as _kernel_cache  # noqa: E402

_kernel_cache.install()  # before any kernel is compiled (graphsvc/kernel_cache.py)
