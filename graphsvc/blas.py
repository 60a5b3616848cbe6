"""BLAS and LAPACK on one thread, for the steps whose results must not depend on how
many threads OpenBLAS is given.

OpenBLAS splits a matrix product or an eigendecomposition over its threads, and the
split changes which of its kernels computes which block, so the last bits of a result
depend on the thread count: on a 2-core machine a product computed with two threads
and with one differ by an ulp here and there. Where such a result is compared or
ranked (the bridges' candidates, the transitions' axes, the learned models of the
piecewise and multilinear strategies, OLNG's subspace), an ulp can change a choice,
and then a graph built by `graphsvc build` and one built in a Dask worker (whose BLAS
gets one thread), or a reconstruction in the CLI and the same one in a batch worker or
a server's thread, would differ. Those steps run inside `one_thread()`: with one thread
a product is the same on every run on a machine. (Across processors the kernels
differ in any case: bytes are the same for the same input, seed and machine.)

OpenBLAS's thread count is one setting for the whole process, and threadpoolctl lets
only one Python thread at a time hold it (another thread's limit is silently ignored
while the first holds it). So `one_thread()` holds a lock for its whole extent: the
thread inside sets one thread, computes and restores the count; another thread that
needs one waits for it. Entering costs about 20 µs; the steps inside are the build's,
a model's learning, a multilinear unit's fit and an OLNG frame's PCA (1–4 ms), which
two streams of one server then take in turn.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np  # noqa: F401  (their BLAS libraries loaded before the controller looks for them)
import scipy.linalg  # noqa: F401
from threadpoolctl import ThreadpoolController

_lock = threading.RLock()  # (re-entrant: a step inside another)
_controller: ThreadpoolController | None = None


@contextmanager
def one_thread() -> Iterator[None]:
    """A context in which BLAS and LAPACK (numpy's and scipy's) run on one thread."""
    global _controller
    with _lock:
        if _controller is None:  # (made on first use: it sees the libraries loaded by then)
            _controller = ThreadpoolController()
        with _controller.limit(limits=1, user_api="blas"):
            yield
