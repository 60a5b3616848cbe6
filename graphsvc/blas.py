"""BLAS and LAPACK on one thread, for the steps whose results must not depend on how
many threads OpenBLAS is given.

OpenBLAS splits a matrix product or an eigendecomposition over its threads, and the
split changes which of its kernels computes which block, so the last bits of a result
depend on the thread count: on a 2-core machine a product computed with two threads
and with one differ by an ulp here and there. Where such a result is compared or
ranked (the bridges' nearest candidates, the refinement's local regression), an ulp
can change a choice, and then a graph built by `graphsvc build` and one built in a
Dask worker (whose BLAS gets one thread), or a reconstruction in the CLI and the same
in a batch worker, would differ. Those steps run inside `one_thread()`: with one thread
a product is the same on every run on a machine. (Across processors the kernels
differ in any case: bytes are the same for the same input, seed and machine.)

The switch costs about 15 µs. It is process-wide: a lock and a count keep nested and
concurrent users from restoring the thread count while another still needs one thread.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np  # noqa: F401  (their BLAS libraries loaded before the controller looks for them)
import scipy.linalg  # noqa: F401
from threadpoolctl import ThreadpoolController

_lock = threading.Lock()
_users = 0
_controller: ThreadpoolController | None = None
_restore = None


@contextmanager
def one_thread() -> Iterator[None]:
    """A context in which BLAS and LAPACK (numpy's and scipy's) run on one thread."""
    global _users, _controller, _restore
    with _lock:
        if _users == 0:
            if _controller is None:  # (created on first use: it sees the libraries loaded by then)
                _controller = ThreadpoolController()
            _restore = _controller.limit(limits=1, user_api="blas")
        _users += 1
    try:
        yield
    finally:
        with _lock:
            _users -= 1
            if _users == 0 and _restore is not None:
                _restore.restore_original_limits()
                _restore = None
