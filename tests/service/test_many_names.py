"""A stream config or recording that names its sensors or markers a hundred thousand
times is refused in one short line (found by fuzzing: the duplicate and mismatch checks
once counted each name against all the others, 89 s for 600 kB of names)."""

from __future__ import annotations

import pytest

from graphsvc.errors import FieldError
from graphsvc.service import convert


def test_duplicate_marker_names_are_named_once_each():
    names = ["walk", "run"] * 50_000 + [f"m{k}" for k in range(20)]
    with pytest.raises(FieldError) as e:
        convert.marker_names_from_proto(names, "config.marker_names")
    assert str(e.value) == "config.marker_names: duplicate marker names: run, walk"


def test_sensor_names_that_are_not_the_layouts_are_listed_up_to_eight():
    given = [f"s{k}" for k in range(100_000)] + ["s7"]
    with pytest.raises(FieldError) as e:
        convert.sensor_order(given, ("a", "b"), "config.sensor_names", "pair")
    text = str(e.value)
    assert "missing a, b" in text and "not in the graph: s0, s1, s2, s3, s4, s5, s6, s7 … (+99992)" in text
    assert "named twice: s7" in text and len(text) < 300
