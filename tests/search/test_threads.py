import threading

import numpy as np
import pytest

from graphsvc.strategies.options import Weights
from graphsvc.strategies.threads import ThreadShare
from graphsvc.strategies.viterbi.search import ViterbiSearch
from tests.search.problems import random_walk_problem


def test_threads_go_to_a_lone_search_one_step_at_a_time():
    share = ThreadShare()
    with share.step() as threaded:
        assert not threaded  # no search registered
    with share.running():
        with share.step() as threaded:
            assert threaded
            with share.step() as inner:  # a second step while the first holds them
                assert not inner
            seen = []
            other = threading.Thread(target=lambda: seen.append(share.step().__enter__()))
            other.start()
            other.join()
            assert seen == [False]
        with share.running():  # a second search: both step serial
            with share.step() as threaded:
                assert not threaded
        with share.step() as threaded:  # alone again
            assert threaded
    assert share.running_searches == 0
    with pytest.raises(RuntimeError), share.running():
        raise RuntimeError("a search that fails still unregisters")
    assert share.running_searches == 0


@pytest.mark.parametrize("weights", [Weights(1, 0, 0), Weights(0.5, 1, 1)])
def test_switching_threads_between_steps_changes_nothing(weights):
    T = 40
    g, meas, position, heading = random_walk_problem(12, T)
    runs = []
    for switching in (False, True):
        s = ViterbiSearch(g, weights, threads=False)
        s.start(position[0], heading[0])
        rows, costs = [], []
        for t in range(1, T):
            s.threads = switching and t % 3 != 0
            assert s.threads == (switching and t % 3 != 0)
            s.step(meas[t], position[t], heading[t])
            rows.append(s.arrivals[(s.first + s.used - 1) % s.arrivals.shape[0]].copy())
            costs.append(s.cost.copy())
        runs.append((np.array(rows), np.array(costs), s.trace(s.best_node())[0]))
    for serial, switched in zip(*runs):
        np.testing.assert_array_equal(serial, switched)


def test_step_timer_runs_the_faster_kind_and_notices_a_change_of_load():
    from graphsvc.strategies.threads import StepTimer

    timer = StepTimer()
    cost = {True: 1.0, False: 2.0}  # an idle machine: threaded steps twice as fast
    chosen = []
    for _ in range(2000):
        kind = timer.choose()
        chosen.append(kind)
        timer.record(kind, cost[kind])
    assert timer.current is True
    probes = chosen.count(False)
    assert 0 < probes < 0.02 * len(chosen)  # the interval grew: few serial probes
    cost = {True: 6.0, False: 3.0}  # another process on every core
    for k in range(2 * StepTimer.MAX_INTERVAL + 8):
        kind = timer.choose()
        timer.record(kind, cost[kind])
        if timer.current is False:
            break
    assert timer.current is False and k <= StepTimer.MAX_INTERVAL + 2 * StepTimer.PROBE_STEPS
    cost = {True: 1.0, False: 2.0}  # idle again: back to the threads within a few probes
    for _ in range(8 * StepTimer.FIRST_INTERVAL):
        kind = timer.choose()
        timer.record(kind, cost[kind])
    assert timer.current is True
