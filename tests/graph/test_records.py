"""A graph's segment and bridge records as columns (`graph.records`) and the graph
file that stores them (format 4): what a build makes comes back from the file equal,
a file of the format before loads to the same graph, and a forged record or edge
order is refused."""

import numpy as np
import pytest

from graphsvc.errors import FormatError
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.file import ARRAYS, FORMAT_VERSION, KIND, load_graph, narrow_index, save_graph
from graphsvc.graph.model import incoming_offsets
from graphsvc.graph.records import BRIDGE_FIELDS, SEGMENT_FIELDS, Records, bridges, segments
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.sensors.layout import PRESETS
from graphsvc.store import read_container, write_container

SEGMENT = {
    "first_node": 7,
    "count": 3,
    "clip_a": 0,
    "clip_b": 1,
    "a_start": 2,
    "a_end": 4,
    "b_start": 5,
    "b_end": 8,
    "theta": 0.025872477788111956,
    "translation": [-0.021746219945778477, 0.042471438063342554],
}
BRIDGE = {
    "first_node": 10,
    "count": 2,
    "clip_a": 1,
    "clip_b": 0,
    "a_entry": 1,
    "b_exit": 14,
    "a_match": 3,
    "b_match": 6,
    "distance_m": 0.05413,
    "kind": "end",
}


def as_format_3(graph, path) -> None:
    """`graph` written as graphsvc wrote graph files before format 4: records as JSON
    in the header, int32 clip / label / bone-set indexes, the CSR offsets stored."""
    save_graph(graph, path)
    meta, arrays, _ = read_container(path, kind=KIND, mmap=False)
    old = {k: v for k, v in arrays.items() if not k.startswith(("segment_", "bridge_"))}
    for name in ("node_clip", "node_bones", "node_label"):
        old[name] = old[name].astype(np.int32)
    old["incoming"] = incoming_offsets(old["edge_dst"], old["node_kind"].shape[0])
    meta = {**meta, "segments": list(graph.segments), "bridges": list(graph.bridges)}
    write_container(path, KIND, meta, old, 3)


def test_records_give_back_the_dicts_they_were_made_from():
    other = {**BRIDGE, "first_node": 12, "kind": "label", "distance_m": 0.1}
    table = bridges([BRIDGE, other])
    assert len(table) == 2 and list(table) == [BRIDGE, other] and table[1] == other and table[-2] == BRIDGE
    assert table.column("kind").tolist() == [1, 0] and table.column("first_node").dtype == np.int32
    assert list(table[1:]) == [other] and list(table.select(np.array([False, True]))) == [other]
    assert table.replaced("first_node", [0, 1]).column("first_node").tolist() == [0, 1]
    assert list(segments([SEGMENT])) == [SEGMENT]  # (float64 columns: the exact values)
    assert table == bridges([BRIDGE, other]) and table != bridges([other, BRIDGE]) and len(segments()) == 0
    with pytest.raises(IndexError):
        table[2]
    with pytest.raises(ValueError, match="sideways not one of label, end, start"):
        bridges([{**BRIDGE, "kind": "sideways"}])
    with pytest.raises(KeyError):
        segments([{k: v for k, v in SEGMENT.items() if k != "theta"}])


def test_records_from_a_containers_arrays_check_their_columns():
    arrays = segments([SEGMENT]).arrays("segment_")
    assert Records.from_arrays(SEGMENT_FIELDS, arrays, "segment_") == segments([SEGMENT])
    with pytest.raises(ValueError, match="segment_count"):
        Records.from_arrays(
            SEGMENT_FIELDS, {**arrays, "segment_count": arrays["segment_count"].astype(np.int64)}, "segment_"
        )
    codes = bridges([BRIDGE]).arrays("bridge_")
    codes["bridge_kind"] = np.array([3], np.uint8)
    with pytest.raises(ValueError, match="outside its 3 kinds"):
        Records.from_arrays(BRIDGE_FIELDS, codes, "bridge_")


def test_index_types_narrow_only_when_the_count_allows():
    v = np.array([0, 5], np.int32)
    assert narrow_index(v, 65_536).dtype == np.uint16 and narrow_index(v, 65_537).dtype == np.int32
    assert narrow_index(v, 32_768, signed=True).dtype == np.int16
    assert narrow_index(v, 32_769, signed=True).dtype == np.int32


@pytest.fixture(scope="module")
def built():
    kb = generate_knowledge_base(seed=0, minutes=1.1)  # (11 interpolated segments, 290 bridges)
    graph, _ = build_graph(kb, BuildOptions(layout=PRESETS["wrists-ankles"], progress=False))
    assert len(graph.segments) and len(graph.bridges)  # (the fixture must hold both)
    return graph


def _same_graph(a, b) -> None:
    for name in (*ARRAYS, "incoming", "edge_up"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.segments == b.segments and a.bridges == b.bridges and a.clips == b.clips


def test_format_4_gives_back_the_built_graph_in_fewer_bytes_than_format_3(built, tmp_path):
    new, old = tmp_path / "g4.graph", tmp_path / "g3.graph"
    save_graph(built, new)
    as_format_3(built, old)
    meta, arrays, version = read_container(new, kind=KIND)
    assert version == FORMAT_VERSION == 4 and "incoming" not in arrays and "segments" not in meta
    assert (arrays["node_clip"].dtype, arrays["node_bones"].dtype, arrays["node_label"].dtype) == (
        np.uint16,
        np.uint16,
        np.int16,
    )
    for path in (new, old):
        _same_graph(load_graph(path), built)
    assert new.stat().st_size < old.stat().st_size
    # A format 3 file written again is a format 4 file, byte for byte the build's.
    save_graph(load_graph(old), tmp_path / "again.graph")
    assert (tmp_path / "again.graph").read_bytes() == new.read_bytes()


@pytest.mark.parametrize(
    "name, edit, says",
    [
        ("bridge_first_node", lambda a: a.__setitem__(-1, 10**8), "bridges name nodes or clips"),
        ("segment_clip_b", lambda a: a.__setitem__(0, 999), "segments name nodes or clips"),
        (
            "edge_dst",
            lambda a: a.__setitem__(0, a[-1]),
            "not sorted by destination",
        ),  # (the first edge into the last node)
    ],
)
def test_a_forged_record_or_edge_order_is_refused(built, tmp_path, name, edit, says):
    path = tmp_path / "g.graph"
    save_graph(built, path)
    meta, arrays, version = read_container(path, kind=KIND, mmap=False)
    arrays = {k: v.copy() for k, v in arrays.items()}
    edit(arrays[name])
    write_container(path, KIND, meta, arrays, version)
    with pytest.raises(FormatError, match=says):
        load_graph(path)
