"""graphsvc.blas.one_thread: BLAS on one thread inside, in whichever thread enters it,
and the count restored after."""

from __future__ import annotations

import threading

from threadpoolctl import ThreadpoolController

from graphsvc.blas import one_thread


def _counts() -> list[int]:
    return [c.num_threads for c in ThreadpoolController().select(user_api="blas").lib_controllers]


def test_one_thread_inside_in_the_main_thread_and_in_others_after_it():
    before = _counts()
    seen = {}

    def inside(tag):
        with one_thread():
            seen[tag] = _counts()
            with one_thread():  # (nested)
                seen[tag + " nested"] = _counts()
        seen[tag + " after"] = _counts()

    inside("main")
    t = threading.Thread(target=inside, args=("thread",))  # (threadpoolctl lets one thread hold the count)
    t.start()
    t.join()
    inside("main again")
    for tag in ("main", "thread", "main again"):
        assert set(seen[tag]) == {1} and set(seen[tag + " nested"]) == {1}, (tag, seen)
        assert seen[tag + " after"] == before, (tag, seen)
