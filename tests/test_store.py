"""The binary container: round trips, determinism, zero-copy mapping, refusal of
every kind of damage, atomic writes."""

from __future__ import annotations

import mmap
import os
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from graphsvc.errors import FormatError, InputError
from graphsvc.store import ALIGN, MAGIC, read_container, read_header, write_container


def sample_arrays() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(7)
    return {
        "acc": rng.normal(size=(5, 2, 3)).astype(np.float32),
        "t": np.arange(5, dtype=np.float64) / 30,
        "idx": np.arange(7, dtype=np.int64),
        "big_endian": np.arange(4, dtype=">i4"),
        "flags": np.array([True, False, True]),
        "names": np.array(["l_wrist", "r_ankle"]),
        "raw": np.array([b"ab", b"xyz"]),
        "c": np.array([1 + 2j], dtype=np.complex64),
        "empty": np.zeros((0, 3), np.float32),
        "scalar": np.float64(2.5),
        "half": np.array([1.5, np.nan], dtype=np.float16),
        "strided": np.arange(12.0).reshape(3, 4).T,  # not C-contiguous
    }


META = {"rate_hz": 30.0, "names": ["a", "b"], "nested": {"z": 1, "a": [1.5, None]}, "unicode": "µs, °"}


@pytest.fixture
def written(tmp_path):
    path = tmp_path / "x.bin"
    write_container(path, "recording", META, sample_arrays(), 3)
    return path


def assert_arrays_equal(got: dict, want: dict) -> None:
    assert sorted(got) == sorted(want)
    for k, w in want.items():
        w = np.asarray(w)
        assert got[k].shape == w.shape, k
        assert got[k].dtype == w.dtype.newbyteorder("<") or got[k].dtype == w.dtype, k
        np.testing.assert_array_equal(got[k], w, err_msg=k)


@pytest.mark.parametrize("use_mmap", [True, False])
def test_round_trip(written, use_mmap):
    meta, arrays, version = read_container(written, kind="recording", mmap=use_mmap)
    assert meta == META
    assert version == 3
    assert_arrays_equal(arrays, sample_arrays())
    assert arrays["big_endian"].dtype.str == "<i4"
    assert arrays["scalar"].shape == ()


def test_named_fields(written):
    c = read_container(written)
    assert c.format_version == 3 and c.meta["rate_hz"] == 30.0 and set(c.arrays) == set(sample_arrays())


def test_layout_is_aligned_and_sorted(written):
    header = read_header(written)
    names = [e["name"] for e in header["arrays"]]
    assert names == sorted(names)
    assert all(e["offset"] % ALIGN == 0 for e in header["arrays"])
    data = written.read_bytes()
    assert data[:8] == MAGIC
    (header_len,) = struct.unpack_from("<Q", data, 16)
    assert (24 + header_len) % ALIGN == 0
    assert len(data) == 24 + header_len + header["data_size"] + 48


def test_deterministic(tmp_path):
    a, b = tmp_path / "a.bin", tmp_path / "b.bin"
    write_container(a, "graph", dict(META), sample_arrays(), 1)
    # Same content, different dict order and memory layout.
    arrays = dict(reversed(list(sample_arrays().items())))
    arrays["acc"] = np.asfortranarray(arrays["acc"])
    write_container(b, "graph", dict(reversed(list(META.items()))), arrays, 1)
    assert a.read_bytes() == b.read_bytes()


def test_mmap_is_zero_copy_and_read_only(written):
    _, arrays, _ = read_container(written, mmap=True)
    acc = arrays["acc"]
    assert not acc.flags.writeable and not acc.flags.owndata
    with pytest.raises(ValueError):
        acc[0, 0, 0] = 1.0

    # The base chain ends in the memory map: nothing was copied, and every array
    # is a view of the same single mapping.
    def root(a):
        while isinstance(a, np.ndarray):
            a = a.base
        return a

    assert isinstance(root(acc), memoryview) and isinstance(root(acc).obj, mmap.mmap)
    assert root(arrays["t"]) is root(acc)
    assert not np.shares_memory(arrays["acc"], arrays["t"])
    assert acc.ctypes.data % ALIGN == 0  # pages are aligned, so the arrays are too


def test_no_mmap_arrays_are_writable(written):
    _, arrays, _ = read_container(written, mmap=False)
    arrays["acc"][0, 0, 0] = 1.0
    assert arrays["acc"][0, 0, 0] == 1.0
    assert read_container(written)[1]["acc"][0, 0, 0] != 1.0


def test_wrong_kind(written):
    with pytest.raises(FormatError, match="expected a graph, got a recording"):
        read_container(written, kind="graph")


def test_object_array_refused(tmp_path):
    with pytest.raises(InputError, match="dtype object"):
        write_container(tmp_path / "o.bin", "graph", {}, {"o": np.array([1, "a"], dtype=object)}, 1)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "arrays,meta",
    [
        ({"s": np.zeros(2, dtype=[("a", "f4")])}, {}),
        ({"d": np.array(["2020-01-01"], dtype="datetime64[D]")}, {}),
        ({"": np.zeros(2)}, {}),
        ({}, {"x": object()}),
        ({}, {"x": float("nan")}),
    ],
)
def test_unstorable_refused(tmp_path, arrays, meta):
    with pytest.raises(InputError):
        write_container(tmp_path / "o.bin", "graph", meta, arrays, 1)
    assert list(tmp_path.iterdir()) == []


def test_missing_folder(tmp_path):
    target = tmp_path / "nope" / "x.bin"
    with pytest.raises(InputError, match="nope"):
        write_container(target, "graph", {}, {"a": np.zeros(3)}, 1)
    assert list(tmp_path.iterdir()) == []


def test_failed_write_keeps_target(written, monkeypatch):
    before = written.read_bytes()
    # An object array fails validation before anything is written...
    with pytest.raises(InputError):
        write_container(written, "recording", {}, {"a": np.zeros(3), "o": np.array([None])}, 1)
    assert written.read_bytes() == before

    # ...and a failure midway (here: at fsync, after all bytes went out) removes
    # the temporary file and leaves the old target intact.
    def broken_fsync(fd):
        raise OSError(5, "I/O error")

    monkeypatch.setattr(os, "fsync", broken_fsync)
    with pytest.raises(OSError):
        write_container(written, "recording", {}, {"a": np.zeros(1000)}, 1)
    monkeypatch.undo()
    assert written.read_bytes() == before
    assert [p.name for p in written.parent.iterdir()] == [written.name]


def test_overwrite_replaces(written):
    write_container(written, "graph", {"new": True}, {"a": np.ones(2)}, 2)
    meta, arrays, version = read_container(written, kind="graph")
    assert meta == {"new": True} and version == 2
    assert [p.name for p in written.parent.iterdir()] == [written.name]


# ---------------------------------------------------------------- damage


def refused(path, data: bytes, verify: bool = True) -> FormatError:
    path.write_bytes(data)
    with pytest.raises(FormatError) as info:
        read_container(path, verify=verify)
    return info.value


def test_not_a_graphsvc_file(tmp_path):
    err = refused(tmp_path / "x", b"HIERARCHY\nROOT Hips\n" * 10)
    assert "not a graphsvc file" in str(err)


def test_empty_file(tmp_path):
    assert "truncated" in str(refused(tmp_path / "x", b""))


def test_unsupported_version(written):
    data = bytearray(written.read_bytes())
    struct.pack_into("<I", data, 8, 99)
    assert "unsupported container version 99" in str(refused(written, bytes(data)))


def test_checksum_mismatch(written):
    data = bytearray(written.read_bytes())
    header = read_header(written)
    acc = next(e for e in header["arrays"] if e["name"] == "acc")
    data[len(data) - 48 - header["data_size"] + acc["offset"]] ^= 0x01  # one bit of array data
    err = refused(written, bytes(data))
    assert "file is corrupted" in str(err)
    # Without verification the damage goes unnoticed, by design.
    read_container(written, verify=False)


def test_malformed_header(tmp_path):
    path = tmp_path / "x.bin"
    write_container(path, "graph", {}, {"a": np.zeros(2)}, 1)
    data = bytearray(path.read_bytes())
    data[24] = ord("[")  # JSON now malformed
    assert "file is corrupted" in str(refused(path, bytes(data)))
    assert "malformed header" in str(refused(path, bytes(data), verify=False))


def test_array_out_of_bounds(tmp_path):
    path = tmp_path / "x.bin"
    write_container(path, "graph", {}, {"a": np.zeros(2)}, 1)
    text = path.read_bytes().replace(b'"nbytes":16', b'"nbytes":99')
    assert "out of bounds" in str(refused(path, text, verify=False))


def test_trailing_bytes(written):
    assert "unexpected" in str(refused(written, written.read_bytes() + b"\0"))


def test_every_byte_flip_refused(tmp_path):
    path = tmp_path / "x.bin"
    write_container(path, "recording", {"k": 1}, {"a": np.arange(3.0), "b": np.array(["x"])}, 1)
    good = path.read_bytes()
    bad = tmp_path / "bad.bin"
    for i in range(len(good)):
        data = bytearray(good)
        data[i] ^= 0xFF
        bad.write_bytes(bytes(data))
        with pytest.raises(FormatError):
            read_container(bad)


def test_every_truncation_refused(tmp_path):
    path = tmp_path / "x.bin"
    write_container(path, "recording", {"k": 1}, {"a": np.arange(3.0)}, 1)
    good = path.read_bytes()
    bad = tmp_path / "bad.bin"
    for n in range(len(good)):
        bad.write_bytes(good[:n])
        for verify in (True, False):
            with pytest.raises(FormatError):
                read_container(bad, verify=verify)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.data())
def test_damage_property(tmp_path, data):
    path = tmp_path / "p.bin"
    arrays = sample_arrays()
    write_container(path, "recording", META, arrays, 1)
    good = path.read_bytes()
    bad = tmp_path / "p_bad.bin"
    pos = data.draw(st.integers(0, len(good) - 1), label="position")
    flip = data.draw(st.integers(1, 255), label="xor")
    damaged = bytearray(good)
    damaged[pos] ^= flip
    bad.write_bytes(bytes(damaged))
    with pytest.raises(FormatError):
        read_container(bad)
    cut = data.draw(st.integers(0, len(good) - 1), label="truncate at")
    bad.write_bytes(good[:cut])
    with pytest.raises(FormatError):
        read_container(bad, verify=False)


def test_missing_file(tmp_path):
    with pytest.raises(FormatError, match="no such file"):
        read_container(tmp_path / "absent.bin")
