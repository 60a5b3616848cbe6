"""numba's OpenMP threads told to wait politely, before any kernel starts them.

The search's threaded kernels are short (tenths of a millisecond) and many; between
them numba's OpenMP workers spin, by GNU OpenMP's default for 300,000 rounds, before
they sleep. On an idle machine that keeps them ready; beside another CPU-bound
process, a spinning worker takes the core from the thread the next kernel waits for.
A batch search (the generated 100,686-node graph, 720 samples, positions and heading)
took 9.4–13.9 s beside one busy process per core against 2.1–2.6 s alone; with 100,000
rounds 3.7–4.4 s against 1.9–2.1 s alone, and with the passive policy (no spinning)
4.2 s against 2.7 s alone (`tools/bench_load.py`). So the package sets GOMP_SPINCOUNT
to 100,000 unless the user has set it or OMP_WAIT_POLICY. GNU OpenMP reads them when
numba first loads it, which is after this module runs (graphsvc's `__init__`).
Whether a step uses the threads at all is decided by its measured speed
(`strategies.threads.StepTimer`).
"""

from __future__ import annotations

import os

SPIN_COUNT = "100000"
# OpenBLAS's threads busy-wait after a product the same way (2^28 cycles by default),
# taking the cores from numba's threads in the kernel that follows: the SSG, which
# alternates a matrix product and a threaded kernel every window, ran 15.6 s of input a
# second with the default and 28.6 with 2^4 cycles (OPENBLAS_THREAD_TIMEOUT=4, the
# least OpenBLAS takes; the products themselves stay threaded; dataset 2 of Bandai,
# hands-feet markers). OpenBLAS reads it when numpy first loads it, so this module runs
# before anything imports numpy (graphsvc's `__init__`).
BLAS_TIMEOUT = "4"


def configure() -> None:
    if "OMP_WAIT_POLICY" not in os.environ and "GOMP_SPINCOUNT" not in os.environ:
        os.environ["GOMP_SPINCOUNT"] = SPIN_COUNT
    os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", BLAS_TIMEOUT)
