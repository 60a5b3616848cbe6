"""Values derived from a motion graph in this process — the search's index, a
strategy's prepared index, the synthesis lookups — held beside the graph object, not
as attributes on it: made once per graph object (a copy gets its own) and dropped
when the graph is.

A value must not refer to its graph (or only weakly): it would keep the graph alive.
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable, Hashable
from typing import TypeVar

T = TypeVar("T")

_HELD: weakref.WeakKeyDictionary[object, dict] = weakref.WeakKeyDictionary()
_LOCK = threading.RLock()  # (re-entrant: a value's make may derive another value)


def derived(graph, key: Hashable, make: Callable[[], T]) -> T:
    """The graph's value under `key`, made by make() on first use (once, whichever
    thread asks first; the others wait for it)."""
    with _LOCK:
        values = _HELD.get(graph)
        if values is None:
            values = _HELD[graph] = {}
        if key not in values:
            values[key] = make()
        return values[key]


def forget(graph, key: Hashable) -> None:
    """Drop the graph's value under `key` (made again on next use)."""
    with _LOCK:
        _HELD.get(graph, {}).pop(key, None)
