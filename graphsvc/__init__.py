"""graphsvc: full-body human motion from sparse measurements by searching motion capture."""

from graphsvc import kernel_cache as _kernel_cache

_kernel_cache.install()  # before any kernel is compiled: see graphsvc/kernel_cache.py
