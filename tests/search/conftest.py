"""Fixtures shared by the search tests."""

import pytest

from graphsvc.strategies.viterbi.search import ViterbiSearch


@pytest.fixture(params=[None, (8, 5), (3, 0), (4, 9)], ids=["ring-default", "ring-8+5", "ring-3+0", "ring-4+9"])
def ring(request, monkeypatch):
    """The dense lattice window's sizes (rows moved or dropped at a time, rows kept
    beyond them): the defaults, which short test inputs never fill, and small ones
    that make them flush into the survivor store (or slide) many times, wrapping the
    ring at offsets that do not divide the input length."""
    if request.param is not None:
        monkeypatch.setattr(ViterbiSearch, "BLOCK", request.param[0])
        monkeypatch.setattr(ViterbiSearch, "STORE_WINDOW", request.param[1])
    return request.param
