"""The threaded search kernels compiled ahead, in a second process.

On a fresh install numba compiles the Viterbi search's kernels on first use: on a
2-core machine about 35 s for the threaded ones, 11 s for the serial ones and 6 s for
synthesis's, one core busy while the other waits. A command that knows it will search
soon (`graphsvc demo`) starts this module as a process first: it warms the threaded
kernels on a small generated graph (their types are those of every graph: the kernels
it writes into numba's disk cache load in about 1.5 s for a built one), while the
command generates, builds and warms the rest on the other core. Once the kernels are
cached the process only loads them (a few seconds beside the command's own work). A
failure here costs nothing but time: the command compiles whatever it finds missing.

    python -m graphsvc.precompile
"""

from __future__ import annotations

import subprocess
import sys


def start() -> subprocess.Popen | None:
    """Start the process (None if it cannot be started)."""
    try:
        return subprocess.Popen(
            [sys.executable, "-m", "graphsvc.precompile"],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    except OSError:
        return None


def wait(process: subprocess.Popen | None, timeout_s: float = 600.0) -> None:
    """Wait for it to finish (killed after timeout_s: the caller then compiles)."""
    if process is None:
        return
    try:
        process.wait(timeout_s)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


def warm_threaded_kernels() -> None:
    # (imported here, in the child process only: the command that starts it does not
    # wait for numba and the search's modules to load)
    import numpy as np

    from graphsvc.graph.model import graph_from_edges
    from graphsvc.strategies.viterbi.batch import warm_up_search

    rng = np.random.default_rng(0)
    nodes = 300
    src = np.repeat(np.arange(nodes), 3)
    dst = rng.integers(0, nodes, src.size)
    graph = graph_from_edges(
        src,
        dst,
        rng.normal(0.0, 9.81, (src.size, 2, 3)),
        offsets=rng.normal(0.0, 0.05, (src.size, 2)),
        dheading=rng.normal(0.0, 0.05, src.size),
    )
    warm_up_search(graph, threads=True)


if __name__ == "__main__":
    warm_threaded_kernels()
