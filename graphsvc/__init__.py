"""graphsvc: full-body human motion from sparse measurements by searching motion capture."""

from graphsvc import kernel_cache as _kernel_cache
from graphsvc import numba_env as _numba_env

_numba_env.configure()  # before numba starts its OpenMP threads (graphsvc/numba_env.py)
_kernel_cache.install()  # before any kernel is compiled (graphsvc/kernel_cache.py)
