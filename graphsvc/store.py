"""The graphsvc binary container: one self-describing, checksummed file format for
recordings now and multi-GB motion-graph files later.

Layout (all integers little-endian)::

    offset 0    8 bytes   magic b"GRAPHSVC"
    offset 8    uint32    container version (CONTAINER_VERSION = 1)
    offset 12   uint32    reserved, 0
    offset 16   uint64    header length H in bytes (JSON plus space padding)
    offset 24   H bytes   UTF-8 JSON header, padded with spaces so the data
                          section starts on a 64-byte boundary (24 + H ≡ 0 mod 64)
    offset D    data      arrays, raw little-endian C-order, each starting on a
                          64-byte boundary (zero padding between), D = 24 + H
    end - 48    trailer   8 bytes b"GSVC-END", uint64 total file length,
                          32 bytes SHA-256 of every byte before the trailer

The header is ``{"arrays": [...], "container": "graphsvc", "data_size": N,
"format_version": int, "kind": str, "meta": {...}}``; each array entry is
``{"dtype": "<f4", "name": ..., "nbytes": ..., "offset": ..., "shape": [...]}`` with
``offset`` counted from the start of the data section (D), entries in sorted name
order. So the whole file length follows from the header (D + data_size + 48), which
is how truncation is told apart from corruption.

Writing is deterministic (sorted JSON keys, fixed separators, no timestamps, arrays
in sorted name order, zero padding): equal inputs give byte-identical files. Writes
are atomic: a temporary file beside the target is written, fsynced and renamed over
it, so a reader never sees half a file and a failed write leaves the old one intact.

Reading memory-maps the file by default: arrays are read-only views into the
mapping and are not copied, so a multi-GB graph costs no RAM until touched. Such
arrays keep the mapping (and so the file) open for as long as any of them, or any
view of them, is alive; on Windows that also keeps the file from being replaced or
deleted. Pass ``mmap=False`` to read the file into (writable) memory and close it
at once. With ``verify=True`` (the default) the SHA-256 is checked over the mapped
bytes without copying them, so every flipped bit is refused; ``verify=False`` skips
that pass (fast open of a large trusted file) and then only structural damage
(bad magic, truncation, malformed header, out-of-bounds arrays) is detected.
"""

from __future__ import annotations

import hashlib
import json
import math
import mmap as _mmap
import os
import re
import struct
from pathlib import Path
from typing import NamedTuple

import numpy as np

from graphsvc.errors import FormatError, InputError, MissingFileError
from graphsvc.fileio import atomic_writer

MAGIC = b"GRAPHSVC"
END_MAGIC = b"GSVC-END"
CONTAINER_VERSION = 1
ALIGN = 64
_PREAMBLE = struct.Struct("<8sIIQ")  # magic, container version, reserved, header length
_TRAILER = struct.Struct("<8sQ32s")  # end magic, total length, sha-256
# Numeric kinds plus fixed-width bytes (S) and unicode (U). Object, structured (V)
# and datetime arrays have no portable raw representation.
_ALLOWED_KINDS = frozenset("biufcSU")
_DTYPE = re.compile(r"^[<>|=][biufcSU][1-9][0-9]{0,8}$")
_CHUNK = 64 << 20  # bytes per write call, so huge arrays stream through the hash


class Container(NamedTuple):
    """What read_container returns; unpacks as ``meta, arrays, format_version``."""

    meta: dict
    arrays: dict[str, np.ndarray]
    format_version: int


def write_container(path, kind: str, meta: dict, arrays: dict[str, np.ndarray], format_version: int) -> None:
    """Write `arrays` (name → array of any numeric, fixed-width bytes or unicode
    dtype, any shape) and the JSON-able `meta` dict as a `kind` container of the
    caller's `format_version`, atomically.

    Raises InputError for unusable values (object arrays, non-JSON meta, a missing
    output folder) before anything is created at `path`."""
    if not isinstance(kind, str) or not kind:
        raise InputError(f"{path}: container kind must be a non-empty string, got {kind!r}")
    if isinstance(format_version, bool) or not isinstance(format_version, (int, np.integer)):
        raise InputError(f"{path}: format_version must be an integer, got {format_version!r}")
    if not isinstance(meta, dict):
        raise InputError(f"{path}: container meta must be a dict, got {type(meta).__name__}")
    prepared = _prepare_arrays(path, arrays)
    entries, offset = [], 0
    for name, arr in prepared:
        offset = _align(offset)
        entries.append(
            {"name": name, "dtype": arr.dtype.str, "shape": list(arr.shape), "offset": offset, "nbytes": arr.nbytes}
        )
        offset += arr.nbytes
    data_size = _align(offset)
    header = {
        "container": "graphsvc",
        "kind": kind,
        "format_version": int(format_version),
        "meta": meta,
        "arrays": entries,
        "data_size": data_size,
    }
    try:
        text = json.dumps(
            header, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False, default=_json_default
        )
    except (TypeError, ValueError) as e:
        raise InputError(f"{path}: container meta is not JSON-serialisable: {e}") from None
    raw = text.encode("utf-8")
    header_len = _align(_PREAMBLE.size + len(raw)) - _PREAMBLE.size
    raw += b" " * (header_len - len(raw))

    with atomic_writer(path) as f:
        digest = hashlib.sha256()

        def put(data) -> None:
            digest.update(data)
            f.write(data)

        put(_PREAMBLE.pack(MAGIC, CONTAINER_VERSION, 0, header_len))
        put(raw)
        pos = 0
        for (_, arr), entry in zip(prepared, entries):
            put(bytes(entry["offset"] - pos))
            flat = arr.reshape(-1).view(np.uint8)  # contiguous → a zero-copy byte view
            for start in range(0, flat.size, _CHUNK):
                put(flat[start : start + _CHUNK])
            pos = entry["offset"] + entry["nbytes"]
        put(bytes(data_size - pos))
        total = _PREAMBLE.size + header_len + data_size + _TRAILER.size
        f.write(_TRAILER.pack(END_MAGIC, total, digest.digest()))


def read_container(path, kind: str | None = None, mmap: bool = True, verify: bool = True) -> Container:
    """Read a container → Container(meta, arrays, format_version).

    kind: when given, a file of another kind is refused ("expected a recording, got
    a graph"). mmap: True → arrays are read-only zero-copy views of a read-only
    memory map that stays open while any of them lives; False → the file is read
    into memory, closed, and the arrays are writable. verify: check the SHA-256.

    Raises FormatError for anything but a whole, intact container: not a graphsvc
    file, unsupported container version, truncated, corrupted, malformed header,
    arrays out of bounds, wrong kind. Nothing is returned half-loaded."""
    path = Path(path)
    buf = _load_bytes(path, mmap)
    try:
        header = _check(path, buf, verify)
    except FormatError as e:
        # Drop the mapping now: a traceback through _check would keep it alive.
        del buf
        raise e.with_traceback(None) from None
    if kind is not None and header["kind"] != kind:
        raise FormatError(path, f"expected {_article(kind)} {kind}, got {_article(header['kind'])} {header['kind']}")
    start = _PREAMBLE.size + _header_len(buf)
    arrays = {}
    for e in header["arrays"]:
        lo = start + e["offset"]
        arr = buf[lo : lo + e["nbytes"]].view(np.dtype(e["dtype"])).reshape(e["shape"])
        arrays[e["name"]] = arr
    return Container(header["meta"], arrays, header["format_version"])


def read_header(path, verify: bool = False) -> dict:
    """The parsed JSON header of a container (kind, format_version, meta, arrays'
    name/dtype/shape/offset/nbytes, data_size) without loading any array: what an
    `inspect` needs of a multi-GB file. Structural checks always; the checksum
    only with verify=True."""
    path = Path(path)
    return _check(path, _load_bytes(path, True), verify)


def file_checksum(path) -> str:
    """The SHA-256 a container's trailer records (hex), read without loading the file:
    what identifies its contents (caches beside a graph are keyed by it). Structural
    checks only; `read_container(verify=True)` is what proves the bytes match it."""
    path = Path(path)
    size = path.stat().st_size
    if size < _PREAMBLE.size + _TRAILER.size:
        raise FormatError(path, "too short to be a graphsvc container")
    with path.open("rb") as f:
        f.seek(size - _TRAILER.size)
        end_magic, total, digest = _TRAILER.unpack(f.read(_TRAILER.size))
    if end_magic != END_MAGIC or total != size:
        raise FormatError(path, "no container trailer (truncated or not a graphsvc file)")
    return digest.hex()


# ---------------------------------------------------------------- atomic output


# ---------------------------------------------------------------- writing helpers


def _prepare_arrays(path, arrays: dict) -> list[tuple[str, np.ndarray]]:
    """Sorted (name, little-endian C-contiguous array) pairs; InputError for
    anything that has no raw representation."""
    if not isinstance(arrays, dict):
        raise InputError(f"{path}: container arrays must be a dict of name → array")
    out = []
    for name in sorted(arrays, key=lambda n: (not isinstance(n, str), str(n))):
        if not isinstance(name, str) or not name:
            raise InputError(f"{path}: array names must be non-empty strings, got {name!r}")
        arr = np.asarray(arrays[name])
        dt = arr.dtype
        if dt.kind not in _ALLOWED_KINDS or dt.fields is not None or dt.subdtype is not None:
            raise InputError(
                f"{path}: array {name!r} has dtype {dt}, which cannot be stored "
                "(numeric, fixed-width bytes or unicode only)"
            )
        if dt.itemsize == 0:
            raise InputError(f"{path}: array {name!r} has zero-width dtype {dt}")
        # The file is little-endian whatever the machine; a no-op for native data here.
        out.append((name, np.asarray(arr, dtype=dt.newbyteorder("<"), order="C")))
    return out


def _json_default(obj):
    """numpy scalars and arrays in meta become plain JSON values."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (tuple, set, frozenset)):
        return list(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")


def _align(n: int) -> int:
    return -(-n // ALIGN) * ALIGN


# ---------------------------------------------------------------- reading helpers


def _load_bytes(path: Path, use_mmap: bool) -> np.ndarray:
    """The whole file as a uint8 array: a read-only view of a memory map, or an
    in-memory copy. An empty file cannot be mapped, so it is read instead."""
    try:
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            if use_mmap and size > 0:
                return np.frombuffer(_mmap.mmap(f.fileno(), 0, access=_mmap.ACCESS_READ), dtype=np.uint8)
            buf = np.empty(size, np.uint8)  # numpy-allocated → aligned for every dtype
            if f.readinto(memoryview(buf)) != size:
                raise FormatError(path, "file changed size while being read")
            return buf
    except FileNotFoundError:
        raise MissingFileError(path) from None
    except IsADirectoryError:
        raise FormatError(path, "is a folder, not a graphsvc file") from None
    except PermissionError as e:
        raise FormatError(path, f"cannot read: {e.strerror}") from None


def _header_len(buf: np.ndarray) -> int:
    return _PREAMBLE.unpack_from(buf, 0)[3]


def _check(path: Path, buf: np.ndarray, verify: bool) -> dict:
    """Validate the whole structure of `buf`; return the parsed header."""
    size = buf.size
    if size < len(MAGIC) or bytes(buf[: len(MAGIC)]) != MAGIC:
        if MAGIC.startswith(bytes(buf[: len(MAGIC)])):
            raise FormatError(path, f"truncated graphsvc file ({size} bytes)")
        raise FormatError(path, "not a graphsvc file (bad magic bytes)")
    if size < _PREAMBLE.size:
        raise FormatError(path, f"truncated graphsvc file ({size} bytes)")
    _, version, reserved, header_len = _PREAMBLE.unpack_from(buf, 0)
    if version != CONTAINER_VERSION:
        raise FormatError(path, f"unsupported container version {version} (this graphsvc reads {CONTAINER_VERSION})")
    data_start = _PREAMBLE.size + header_len
    if data_start + _TRAILER.size > size:
        raise FormatError(path, f"truncated: header of {header_len} bytes does not fit in {size} bytes")
    if reserved != 0 or data_start % ALIGN:
        raise _damaged(path, buf, verify, "bad preamble")
    try:
        header = json.loads(bytes(buf[_PREAMBLE.size : data_start]).decode("utf-8"))
        _check_header(header)
    except (UnicodeDecodeError, ValueError, TypeError, KeyError, OverflowError, RecursionError) as e:
        raise _damaged(path, buf, verify, f"malformed header ({e})") from None
    expected = data_start + header["data_size"] + _TRAILER.size
    if size < expected:
        raise FormatError(path, f"truncated: {size} bytes, the header declares {expected}")
    if size > expected:
        raise _damaged(path, buf, verify, f"{size - expected} unexpected bytes after the trailer")
    end_magic, total, digest = _TRAILER.unpack_from(buf, size - _TRAILER.size)
    if end_magic != END_MAGIC or total != size:
        raise FormatError(path, "file is corrupted (bad trailer)")
    if verify and _sha256(buf[: size - _TRAILER.size]) != digest:
        raise FormatError(path, "file is corrupted (checksum mismatch)")
    return header


def _damaged(path: Path, buf: np.ndarray, verify: bool, what: str) -> FormatError:
    """A structural fault: when the checksum is also wrong, the file was damaged
    after writing, which is the more useful thing to say."""
    size = buf.size
    if verify and size >= _TRAILER.size:
        _, _, digest = _TRAILER.unpack_from(buf, size - _TRAILER.size)
        if _sha256(buf[: size - _TRAILER.size]) != digest:
            return FormatError(path, f"file is corrupted ({what}; checksum mismatch)")
    return FormatError(path, what)


def _sha256(view: np.ndarray) -> bytes:
    # hashlib reads the buffer in place: no copy of a multi-GB mapping.
    with memoryview(view) as mv:
        return hashlib.sha256(mv).digest()


def _is_int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _check_header(h) -> None:
    """Raise ValueError unless `h` is a well-formed header with in-bounds arrays."""
    if not isinstance(h, dict) or h.get("container") != "graphsvc":
        raise ValueError("not a graphsvc header")
    if not isinstance(h.get("kind"), str) or not _is_int(h.get("format_version")):
        raise ValueError("kind or format_version missing")
    if not isinstance(h.get("meta"), dict) or not isinstance(h.get("arrays"), list):
        raise ValueError("meta or arrays missing")
    data_size = h.get("data_size")
    if not _is_int(data_size) or data_size < 0 or data_size % ALIGN:
        raise ValueError("bad data_size")
    names, end = set(), 0
    for e in h["arrays"]:
        if not isinstance(e, dict) or not isinstance(e.get("name"), str) or e["name"] in names:
            raise ValueError("bad or duplicate array name")
        names.add(e["name"])
        # Only what the writer writes (dtype.str of a numeric, bytes or unicode array):
        # numpy parses other strings as structured dtypes, with errors of every kind.
        text = e.get("dtype")
        dt = np.dtype(text) if isinstance(text, str) and _DTYPE.match(text) else None
        if dt is None or dt.kind not in _ALLOWED_KINDS or dt.itemsize == 0 or dt.fields is not None:
            raise ValueError(f"array {e['name']!r}: bad dtype {e.get('dtype')!r}")
        shape, off, nbytes = e.get("shape"), e.get("offset"), e.get("nbytes")
        if not isinstance(shape, list) or not all(_is_int(n) and n >= 0 for n in shape):
            raise ValueError(f"array {e['name']!r}: bad shape {shape!r}")
        if not (_is_int(off) and _is_int(nbytes)) or off < end or off % ALIGN:
            raise ValueError(f"array {e['name']!r}: bad or overlapping offset")
        if nbytes != math.prod(shape) * dt.itemsize or off + nbytes > data_size:
            raise ValueError(f"array {e['name']!r}: {nbytes} bytes at {off} out of bounds or inconsistent with shape")
        end = off + nbytes


def _article(word: str) -> str:
    return "an" if word[:1].lower() in "aeiou" else "a"
