"""Sharing numba's threads between searches running side by side in one process.

A search step spread over numba's threads takes about half as long on two cores
(G_E, 100,686 nodes: a live push 3.3–3.5 against 6.8–6.9 ms), but several searches
doing so at once only fight over the cores, and numba's `workqueue` threading layer
must not be entered by two threads at once. So a server gives the threads to a step
only while a single search is running, and to one step at a time. Results never
depend on it: the threaded and serial kernels compute the same values.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager


class ThreadShare:
    """`running()` for the lifetime of each search (a live stream, a batch call);
    `step()` around each step or push, which yields whether it may use the threads:
    true only while exactly one search is running and no other step holds them."""

    def __init__(self) -> None:
        self._count_lock = threading.Lock()
        self._running = 0
        self._threads = threading.Lock()  # held by the step using numba's threads

    @property
    def running_searches(self) -> int:
        return self._running

    @contextmanager
    def running(self) -> Iterator[None]:
        with self._count_lock:
            self._running += 1
        try:
            yield
        finally:
            with self._count_lock:
                self._running -= 1

    @contextmanager
    def step(self) -> Iterator[bool]:
        # Never blocks: a step that cannot have the threads runs serial at once.
        if self._running == 1 and self._threads.acquire(blocking=False):
            try:
                yield True
            finally:
                self._threads.release()
        else:
            yield False
