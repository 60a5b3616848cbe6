"""A graph's interpolated segments and bridges as tables of columns.

A graph keeps one record for every interpolated segment and every bridge: which
nodes it made, from which clips and frames, and how (`MotionGraph.segments`,
`MotionGraph.bridges`). On a million-frame knowledge base there are 360,000 of them;
as JSON in the file's header they were 65 MB to parse on every load (a fifth of a
second per 10 MB) and 2 % of the file. A `Records` table holds them as one array a
field (int32, float64, a category's uint8 code), stored in the file beside the node and
edge arrays and memory-mapped like them; consumers read whole columns
(`records.column("first_node")`), and a record still reads as the dict it was built
from (`records[k]`, iteration) where a loop is clearer.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, overload

import numpy as np


@dataclass(frozen=True)
class Field:
    """One column: name, numpy dtype, width (0: a scalar a record, else a list of that
    many numbers), categories (a str field stored as its index in them, uint8)."""

    name: str
    dtype: str
    width: int = 0
    categories: tuple[str, ...] = ()


def _ints(*names: str) -> tuple[Field, ...]:
    return tuple(Field(n, "<i4") for n in names)


# Interpolated segments: first_node, count, clip_a, clip_b, a_start, a_end, b_start,
# b_end (source frames, inclusive), the alignment theta (rad) / translation (m) of b onto a.
SEGMENT_FIELDS = (
    *_ints("first_node", "count", "clip_a", "clip_b", "a_start", "a_end", "b_start", "b_end"),
    Field("theta", "<f8"),
    Field("translation", "<f8", width=2),
)
BRIDGE_KINDS = ("label", "end", "start")  # between actions, out of a clip's end, into its start
# Bridges (`bridges.py`): first_node, count, clip_a, clip_b, a_entry (the frame of a it
# is entered from), b_exit (the frame of b it leaves to), a_match, b_match,
# distance_m, kind (one of BRIDGE_KINDS).
BRIDGE_FIELDS = (
    *_ints("first_node", "count", "clip_a", "clip_b", "a_entry", "b_exit", "a_match", "b_match"),
    Field("distance_m", "<f8"),
    Field("kind", "|u1", categories=BRIDGE_KINDS),
)


class Records:
    """Records of one shape as columns: `len`, `records[k]` (a dict of Python values;
    a slice gives a table), iteration (dicts), `column(name)` (the array), `select(index)`, equality by value."""

    def __init__(self, fields: Sequence[Field], columns: Mapping[str, np.ndarray]):
        self.fields = tuple(fields)
        self._columns = {f.name: columns[f.name] for f in self.fields}
        sizes = {int(np.shape(c)[0]) for c in self._columns.values()}
        if len(sizes) > 1:
            raise ValueError(f"record columns of different lengths: {sorted(sizes)}")
        self._size = sizes.pop() if sizes else 0

    @classmethod
    def from_dicts(cls, fields: Sequence[Field], records: Sequence[Mapping[str, Any]]) -> Records:
        """From dicts holding at least every field (KeyError for a missing one,
        ValueError for a category a field does not have or a list of the wrong width)."""
        columns = {}
        for f in fields:
            values = [r[f.name] for r in records]
            if f.categories:
                lookup = {c: i for i, c in enumerate(f.categories)}
                unknown = sorted({str(v) for v in values} - set(lookup))
                if unknown:
                    raise ValueError(
                        f"record field {f.name}: {', '.join(unknown)} not one of {', '.join(f.categories)}"
                    )
                values = [lookup[v] for v in values]
            shape = (len(values), f.width) if f.width else (len(values),)
            columns[f.name] = np.asarray(values, dtype=f.dtype).reshape(shape)
        return cls(fields, columns)

    @classmethod
    def empty(cls, fields: Sequence[Field]) -> Records:
        return cls.from_dicts(fields, [])

    def __len__(self) -> int:
        return self._size

    def column(self, name: str) -> np.ndarray:
        """The field's values, one row a record (a category's codes for a str field)."""
        return self._columns[name]

    @overload
    def __getitem__(self, k: int) -> dict[str, Any]: ...
    @overload
    def __getitem__(self, k: slice) -> Records: ...
    def __getitem__(self, k: int | slice) -> dict[str, Any] | Records:
        if isinstance(k, slice):
            return self.select(k)
        if not -self._size <= k < self._size:
            raise IndexError(f"record {k} of {self._size}")
        return self._record({f.name: self._columns[f.name][k] for f in self.fields})

    def __iter__(self) -> Iterator[dict[str, Any]]:
        lists = [self._columns[f.name].tolist() for f in self.fields]
        for row in zip(*lists):
            yield self._record(dict(zip((f.name for f in self.fields), row)))

    def _record(self, raw: dict[str, Any]) -> dict[str, Any]:
        out = {}
        for f in self.fields:
            v = raw[f.name]
            v = v.tolist() if isinstance(v, np.ndarray | np.generic) else v
            out[f.name] = f.categories[int(v)] if f.categories else v
        return out

    def select(self, index) -> Records:
        """The records at `index` (a boolean mask or record numbers), as a new table."""
        return Records(self.fields, {name: np.ascontiguousarray(c[index]) for name, c in self._columns.items()})

    def replaced(self, name: str, values) -> Records:
        """A copy with column `name` replaced by `values` (cast to the field's dtype)."""
        f = next(f for f in self.fields if f.name == name)
        return Records(self.fields, {**self._columns, name: np.asarray(values, dtype=f.dtype)})

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Records):
            return NotImplemented
        return self.fields == other.fields and all(
            np.array_equal(self._columns[f.name], other._columns[f.name]) for f in self.fields
        )

    __hash__ = None  # type: ignore[assignment]  # (mutable arrays inside)

    def __repr__(self) -> str:
        return f"Records({len(self)} × {', '.join(f.name for f in self.fields)})"

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        """The columns as a container's arrays, named prefix + field."""
        return {prefix + name: np.ascontiguousarray(c) for name, c in self._columns.items()}

    @classmethod
    def from_arrays(cls, fields: Sequence[Field], arrays: Mapping[str, np.ndarray], prefix: str) -> Records:
        """The table `arrays` (a container's) hold under prefix (KeyError for a missing
        column; ValueError for a column of another dtype or shape, or unequal lengths,
        or a category code out of range)."""
        columns = {}
        for f in fields:
            c = arrays[prefix + f.name]
            if c.dtype != np.dtype(f.dtype) or c.ndim != (2 if f.width else 1) or (f.width and c.shape[1] != f.width):
                raise ValueError(f"record column {prefix + f.name} is {c.dtype}{list(c.shape)}")
            if f.categories and c.size and int(c.max()) >= len(f.categories):
                raise ValueError(f"record column {prefix + f.name} holds a code outside its {len(f.categories)} kinds")
            columns[f.name] = c
        return cls(fields, columns)


def segments(records: Sequence[Mapping[str, Any]] = ()) -> Records:
    """Interpolated segments' records (`SEGMENT_FIELDS`) from dicts."""
    return Records.from_dicts(SEGMENT_FIELDS, records)


def bridges(records: Sequence[Mapping[str, Any]] = ()) -> Records:
    """Bridges' records (`BRIDGE_FIELDS`) from dicts."""
    return Records.from_dicts(BRIDGE_FIELDS, records)


def node_ranges_inside(records: Records, num_nodes: int, num_clips: int) -> bool:
    """True when every record's nodes lie in 0..num_nodes − 1 and its clips in
    0..num_clips − 1 (what a loaded file's records must satisfy before use)."""
    if not len(records):
        return True
    first, count = records.column("first_node").astype(np.int64), records.column("count").astype(np.int64)
    clips = np.concatenate([records.column("clip_a"), records.column("clip_b")])
    return bool(
        first.min() >= 0
        and count.min() >= 0
        and (first + count).max() <= num_nodes
        and clips.min() >= 0
        and clips.max() < num_clips
    )
