"""C3D files read through `ezc3d` (C++) without letting a malformed file crash the
process.

ezc3d follows the offsets and sizes a file declares without checking them against
the file, and indexes parameters it expects without checking their shape: a
parameter with a few hundred dimensions near the end of a truncated file, or
ANALOG:RATE or ANALOG:LABELS given no value, crashes the process (a segmentation
fault, not an exception; found by fuzzing, docs/fuzzing.md). So, first, the
header, every group and parameter record and the sizes of the point, analog and
rotation data are walked here the way ezc3d will read them (`check_c3d`): a file
whose records or data do not fit inside it, a parameter of more than seven
dimensions, a text parameter without one or a number parameter without a value is
refused with a FormatError, and what ezc3d allocates is bounded by the file's size.
Then ezc3d reads the file in a child process (`read_isolated`, about 0.15 s more
a file), so whatever else it cannot survive ends that process, not the caller's: a
FormatError here.

Layout (C3D file format user guide, C3D.org): a 512-byte header (byte 0 the
parameter section's first block, byte 1 0x50; 16-bit words: 2 points, 3 analog
samples a frame, 4 and 5 first and last frame, 7–8 the scale (float; negative:
float data), 9 the data's first block); the parameter section (4 bytes: reserved,
0x50, its length in blocks, processor type 84 Intel, 85 DEC, 86 MIPS big-endian),
then records: int8 name length (negative: locked; 0: the end), int8 id (negative:
a group, positive: a parameter of that group), the name, a 16-bit offset to the
next record (0: the last one); a group then has its description (uint8 length and
text); a parameter its type (−1 char, 1 byte, 2 int16, 4 float), uint8 dimension
count, the dimensions (uint8 each), the values, and its description.
"""

from __future__ import annotations

import io
import json
import math
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np

from graphsvc.errors import FormatError

BLOCK = 512
MAX_DIMENSIONS = 7  # the C3D format allows up to seven
_TYPES = {-1: 1, 1: 1, 2: 2, 4: 4}
PROCESSORS = {84: "<", 85: "<", 86: ">"}


def _float(raw: bytes, order: str, processor: int) -> float:
    if processor == 85:  # DEC: the two 16-bit halves swapped, exponent biased by 2 more
        raw = raw[2:4] + raw[0:2]
        return struct.unpack("<f", raw)[0] / 4.0
    return struct.unpack(order + "f", raw)[0]


def check_c3d(path, data: bytes) -> dict:
    """Check the structure of a C3D file's bytes (module docstring); FormatError for
    what does not fit. Returns what the walk found: processor, points, frames,
    analog samples a frame, and the integer parameters it reads (POINT:USED, ...)."""
    path = Path(path)
    size = len(data)

    def fail(message: str):
        raise FormatError(path, f"not a readable C3D file: {message}")

    if size < BLOCK:
        fail(f"{size} bytes, shorter than a C3D header ({BLOCK})")
    if data[1] != 0x50:
        fail("no C3D key (0x50) in the header's second byte")
    param_block = data[0]
    start = BLOCK * (param_block - 1)
    if param_block < 2 or start + 4 > size:
        fail(f"the parameter section's block {param_block} is not in the file")
    blocks, processor = data[start + 2], data[start + 3]
    if processor not in PROCESSORS:
        fail(f"unknown processor type {processor} (84 Intel, 85 DEC, 86 MIPS)")
    order = PROCESSORS[processor]
    end = start + BLOCK * blocks
    if blocks == 0 or end > size:
        fail(f"the parameter section ({blocks} blocks from block {param_block}) does not fit in {size} bytes")
    params = _walk_parameters(data, start + 4, end, order, processor, fail)

    u16 = struct.Struct(order + "H")
    points, analogs, first, last = (u16.unpack_from(data, k)[0] for k in (2, 4, 6, 8))
    scale = _float(data[12:16], order, processor)
    data_block = u16.unpack_from(data, 16)[0]
    frames = last - first + 1 if last != 65535 else 0
    frames = max(frames, params.get(("POINT", "FRAMES"), 0))
    points = max(points, params.get(("POINT", "USED"), 0))
    width = 4 if not (math.isfinite(scale) and scale >= 0) else 2
    data_start = BLOCK * (data_block - 1)
    if data_block < 1 or data_start < end or data_start > size:
        fail(f"the data's first block {data_block} is not after the parameters in the file")
    need = max(frames, 0) * (points * 4 + analogs) * width
    if need > size - data_start:
        fail(
            f"truncated: {frames} frames of {points} points and {analogs} analog samples need {need} bytes of data, "
            f"the file holds {size - data_start}"
        )
    rotations = params.get(("ROTATION", "USED"), 0)
    if rotations > 0:
        rot_block = params.get(("ROTATION", "DATA_START"), 0)
        ratio = max(params.get(("ROTATION", "RATIO"), 1), 1)
        rot_need = max(frames, 0) * ratio * rotations * 16 * 4  # a 4×4 float matrix each
        if rot_block < 1 or BLOCK * (rot_block - 1) + rot_need > size:
            fail(f"truncated: {rotations} rotations at block {rot_block} do not fit in the file")
    return {"processor": processor, "points": points, "frames": frames, "analogs": analogs, "params": params}


# Parameters ezc3d reads the first value of, whose absence crashes it.
_SCALARS = {
    ("POINT", "USED"),
    ("POINT", "SCALE"),
    ("POINT", "RATE"),
    ("POINT", "DATA_START"),
    ("POINT", "FRAMES"),
    ("ANALOG", "USED"),
    ("ANALOG", "RATE"),
    ("ANALOG", "GEN_SCALE"),
    ("FORCE_PLATFORM", "USED"),
    ("ROTATION", "USED"),
    ("ROTATION", "RATE"),
    ("ROTATION", "DATA_START"),
    ("ROTATION", "RATIO"),
}
_INT_PARAMS = {
    ("POINT", "USED"),
    ("POINT", "FRAMES"),
    ("ANALOG", "USED"),
    ("ROTATION", "USED"),
    ("ROTATION", "DATA_START"),
    ("ROTATION", "RATIO"),
}


def _walk_parameters(data: bytes, i: int, end: int, order: str, processor: int, fail) -> dict:
    """Walk the records from byte i to the section's end as ezc3d reads them; the
    integer values of `_INT_PARAMS` (group, name) → int."""
    groups: dict[int, str] = {}
    pending: list[tuple[int, str, int]] = []  # (group id, name, value) before their group is named
    values: dict = {}
    i16 = struct.Struct(order + "h")
    u16 = struct.Struct(order + "H")
    while True:
        if i + 2 > end:
            fail("a parameter record runs past the parameter section")
        name_len = abs(struct.unpack_from("b", data, i)[0])
        if name_len == 0:
            break
        gid = struct.unpack_from("b", data, i + 1)[0]
        if gid == 0:
            fail(f"a parameter record at byte {i} has group id 0")
        j = i + 2 + name_len
        if j + 2 > end:
            fail(f"a parameter record at byte {i} runs past the parameter section")
        name = data[i + 2 : j].decode("latin-1").upper()
        offset = u16.unpack_from(data, j)[0]
        nxt = 0 if offset == 0 else j + offset
        k = j + 2
        if gid < 0:
            groups[-gid] = name
            if k + 1 > end or k + 1 + data[k] > end:
                fail(f"group {name!r}: its description runs past the parameter section")
            k += 1 + data[k]
        else:
            if k + 2 > end:
                fail(f"parameter {name!r} runs past the parameter section")
            kind = struct.unpack_from("b", data, k)[0]
            ndim = data[k + 1]
            if kind not in _TYPES:
                fail(f"parameter {name!r}: unknown data type {kind}")
            if ndim > MAX_DIMENSIONS:
                fail(f"parameter {name!r}: {ndim} dimensions (at most {MAX_DIMENSIONS})")
            k += 2
            if k + ndim > end:
                fail(f"parameter {name!r}: its dimensions run past the parameter section")
            count = math.prod(data[k : k + ndim])
            k += ndim
            nbytes = _TYPES[kind] * count
            if k + nbytes + 1 > end or k + nbytes + 1 + data[k + nbytes] > end:
                fail(f"parameter {name!r}: its {count} values run past the parameter section")
            if kind == -1 and ndim == 0:
                fail(f"parameter {name!r}: text without a length (no dimensions)")
            v = None
            if count >= 1 and kind in (1, 2, 4):
                raw = data[k : k + _TYPES[kind]]
                v = raw[0] if kind == 1 else i16.unpack(raw)[0] if kind == 2 else _float(raw, order, processor)
                if kind == 2 and v < 0:
                    v += 65536  # counts above 32767 are stored unsigned
                v = int(v) if math.isfinite(v) and abs(v) < 2**40 else 0
            pending.append((gid, name, v))
            k += nbytes
            k += 1 + data[k]
        if nxt == 0:
            break
        if nxt != k and nxt < k:
            fail(f"record {name!r}: the offset to the next record points back into it")
        if nxt > end:
            fail(f"record {name!r}: the next record is past the parameter section")
        i = nxt
    for gid, name, v in pending:
        key = (groups.get(gid, ""), name)
        if key in _SCALARS and v is None:
            fail(f"parameter {key[0]}:{name} has no value")
        if key in _INT_PARAMS:
            values[key] = v
    return values


# ---------------------------------------------------------------- reading in a child

# What the child runs: only numpy and ezc3d, no graphsvc (fast to start). It writes an
# .npz of the points, their residuals and a JSON of the header and POINT parameters
# read_c3d uses to stdout; an ezc3d exception → exit 3 and its first line on stderr.
_CHILD = """
import io, json, resource, sys
import numpy as np
limit = int(sys.argv[2])
resource.setrlimit(resource.RLIMIT_AS, (limit, resource.getrlimit(resource.RLIMIT_AS)[1]))
import ezc3d
try:
    c = ezc3d.c3d(sys.argv[1])
    header = {k: (float(v) if k == "frame_rate" else int(v)) for k, v in c["header"]["points"].items()
              if k in ("frame_rate", "first_frame", "last_frame")}
    point = c["parameters"].get("POINT", {})
    params = {k: [str(x) for x in np.ravel(point[k]["value"])] for k in point
              if k.startswith("LABELS") or k in ("UNITS", "Y_SCREEN")}
    points = np.asarray(c["data"]["points"], dtype=np.float64)
    residuals = np.asarray(c["data"]["meta_points"]["residuals"], dtype=np.float64)
except (RuntimeError, OSError, ValueError, IndexError, KeyError, TypeError, MemoryError) as exc:
    sys.stderr.write((str(exc).splitlines() or [type(exc).__name__])[0][:200])
    sys.exit(3)
out = io.BytesIO()
meta = json.dumps({"header": header, "params": params}).encode()
np.savez(out, points=points, residuals=residuals, meta=np.frombuffer(meta, np.uint8))
sys.stdout.buffer.write(out.getvalue())
"""
CHILD_TIMEOUT_S = 120.0
CHILD_MEMORY = 1 << 30  # address space beyond 32× the file's size


def read_isolated(path, size: int) -> dict:
    """ezc3d's reading of a C3D file (checked by `check_c3d` first), done in a child
    process: {"header": {frame_rate, first_frame, last_frame}, "params": POINT's
    LABELS*, UNITS and Y_SCREEN as lists of text, "points": (4, M, F), "residuals"}.
    FormatError when ezc3d refuses the file, crashes on it or does not finish."""
    path = Path(path)
    limit = CHILD_MEMORY + 32 * size + (1 << 30)  # + what the interpreter, numpy and ezc3d map
    try:
        run = subprocess.run(
            [sys.executable, "-c", _CHILD, str(path), str(limit)],
            capture_output=True,
            timeout=CHILD_TIMEOUT_S,
            stdin=subprocess.DEVNULL,
        )
    except subprocess.TimeoutExpired:
        raise FormatError(path, f"not a readable C3D file: ezc3d did not finish in {CHILD_TIMEOUT_S:g} s") from None
    if run.returncode == 3:
        raise FormatError(path, f"not a readable C3D file: {run.stderr.decode('utf-8', 'replace')}")
    if run.returncode != 0:
        how = f"signal {-run.returncode}" if run.returncode < 0 else f"exit {run.returncode}"
        raise FormatError(path, f"not a readable C3D file: ezc3d failed on it ({how})")
    with np.load(io.BytesIO(run.stdout)) as z:
        out = json.loads(z["meta"].tobytes())
        out["points"], out["residuals"] = z["points"], z["residuals"]
    return out
