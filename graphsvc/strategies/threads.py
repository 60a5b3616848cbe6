"""Sharing numba's threads between searches running side by side in one process, and
using them only where they make a step faster.

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


class StepTimer:
    """Whether a search that may use numba's threads uses them for its next step, from
    the measured time of its recent steps each way.

    On a busy machine (another process on every core, a CPU quota) a threaded step
    waits at every barrier for a thread the scheduler has taken off its core, and
    numba's OpenMP threads spin while they wait: steps measured 1.6–3.6 times slower
    than serial ones there, against 1.3–1.6 times faster on an idle machine. Both
    kinds compute the same values, so the choice only changes speed: the search runs
    the faster kind by a running mean of each kind's step time, and every `interval`
    steps tries the other for PROBE_STEPS steps (the interval doubles, up to
    MAX_INTERVAL, each time the other kind loses, and starts again at FIRST_INTERVAL
    when it wins), so a change of load is noticed within a second or two and a
    steady machine pays a probe step in a few hundred."""

    FIRST_INTERVAL = 16
    MAX_INTERVAL = 512
    PROBE_STEPS = 2
    WEIGHT = 0.25  # of the newest step in a running mean

    def __init__(self) -> None:
        self.mean = {True: None, False: None}  # seconds a step, threaded / serial
        self.current = True
        self.interval = self.FIRST_INTERVAL
        self._since = 0  # steps since the last probe
        self._probing = 0  # probe steps left
        self._probe_seconds = 0.0

    def choose(self) -> bool:
        """Whether the next step should be threaded."""
        if self._probing:
            return not self.current
        if self._since >= self.interval:
            self._probing, self._since = self.PROBE_STEPS, 0
            return not self.current
        return self.current

    def record(self, threaded: bool, seconds: float) -> None:
        """A step's time (s), taken the way `choose` said. A probe's steps give the other
        kind's time afresh (its running mean would be as old as the last probe)."""
        if threaded == self.current:
            m = self.mean[threaded]
            self.mean[threaded] = seconds if m is None else (1 - self.WEIGHT) * m + self.WEIGHT * seconds
            self._since += 1
            return
        self._probe_seconds += seconds
        self._probing -= 1
        if self._probing == 0:
            self.mean[threaded] = self._probe_seconds / self.PROBE_STEPS
            self._probe_seconds = 0.0
            if self.mean[self.current] is None or self.mean[threaded] < self.mean[self.current]:
                self.current, self.interval = threaded, self.FIRST_INTERVAL
            else:
                self.interval = min(2 * self.interval, self.MAX_INTERVAL)
