"""BVH (Biovision hierarchy) reading and writing.

Reading is split in two: the HIERARCHY section is small and parsed token by token
in Python (so every error names its line); the MOTION block is most of the file and
is parsed by one compiled pass over the raw bytes (`parse_rows`), which checks the
shape of every row while it converts numbers. Channel values become local
quaternions and translations in a second compiled pass (`_channels_to_pose`).

Conventions (see skeleton.py): rotations are intrinsic in the order the channels
are listed ("Zrotation Xrotation Yrotation" means R = Rz·Rx·Ry, as quat.from_euler
with order "ZXY"); a joint's position channels replace its OFFSET; End Sites become
joints without channels named `<parent>_End` (or the End Site's own name).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import NoReturn

import numba
import numpy as np

from graphsvc.errors import FormatError, InputError
from graphsvc.fileio import StrPath, read_input_bytes, write_text_atomic
from graphsvc.motion import quat
from graphsvc.motion.skeleton import Motion, Skeleton

# Channel name (lower case) → code: 0..2 position x/y/z, 3..5 rotation x/y/z.
CHANNEL_CODES = {
    "xposition": 0,
    "yposition": 1,
    "zposition": 2,
    "xrotation": 3,
    "yrotation": 4,
    "zrotation": 5,
}
CHANNEL_NAMES = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")

# Auto unit detection: figure size (longest leaf-to-leaf bone path) above which the
# file is taken to be in centimetres / millimetres. The longest path of a tall performer
# runs from a hand tip to the opposite toe tip: 2.7 m for a 2 m adult, 3.4 m for a 2.5 m
# one, while a figure in millimetres measures in the thousands.
CM_ABOVE = 20.0
MM_ABOVE = 400.0

# ---------------------------------------------------------------------------
# Compiled number parsing (shared with asfamc.py)
# ---------------------------------------------------------------------------

_POW10 = np.array([10.0**k for k in range(23)])

OK, ERR_COUNT, ERR_NUMBER, ERR_EXTRA_ROWS, ERR_FEW_ROWS = 0, 1, 2, 3, 4


@numba.njit(cache=True, nogil=True, inline="always")
def _is_space(c):
    return c == 32 or c == 9 or c == 13 or c == 11 or c == 12


@numba.njit(cache=True, nogil=True)
def parse_number(buf, i, pow10):
    """Parse one decimal float token starting at buf[i]. Returns (value, next index,
    ok). Exact (correctly rounded) for up to 15 significant digits, the common case
    of exporter output; longer mantissas are within an ulp or two. Accepts nan/inf
    spellings as Python's float() does so that they surface as non-finite values."""
    n = buf.size
    neg = False
    c = buf[i]
    if c == 45 or c == 43:  # - +
        neg = c == 45
        i += 1
        if i >= n:
            return 0.0, i, False
    c = buf[i] | 32  # lower-case letters
    if c == 110 or c == 105:  # 'n' or 'i': nan / inf / infinity
        j = i
        while j < n and not _is_space(buf[j]) and buf[j] != 10:
            j += 1
        word = buf[i:j]
        lw = word.size
        if lw == 3 and (word[0] | 32) == 110 and (word[1] | 32) == 97 and (word[2] | 32) == 110:
            return np.nan, j, True
        if (lw == 3 or lw == 8) and (word[0] | 32) == 105 and (word[1] | 32) == 110 and (word[2] | 32) == 102:
            if lw == 3:
                return -np.inf if neg else np.inf, j, True
            tail = word[3:]
            ref = np.array([105, 110, 105, 116, 121], dtype=np.uint8)  # "inity"
            same = True
            for k in range(5):
                if (tail[k] | 32) != ref[k]:
                    same = False
            if same:
                return -np.inf if neg else np.inf, j, True
        return 0.0, j, False
    mant = np.int64(0)
    nd = 0  # significant digits kept in mant
    exp10 = 0
    digits = 0
    while i < n and 48 <= buf[i] <= 57:
        d = buf[i] - 48
        digits += 1
        if mant == 0 and d == 0:
            pass
        elif nd < 18:
            mant = mant * 10 + d
            nd += 1
        else:
            exp10 += 1  # dropped integer digit
        i += 1
    if i < n and buf[i] == 46:  # '.'
        i += 1
        while i < n and 48 <= buf[i] <= 57:
            d = buf[i] - 48
            digits += 1
            if mant == 0 and d == 0:
                exp10 -= 1
            elif nd < 18:
                mant = mant * 10 + d
                nd += 1
                exp10 -= 1
            i += 1
    if digits == 0:
        return 0.0, i, False
    if i < n and (buf[i] | 32) == 101:  # 'e'
        i += 1
        eneg = False
        if i < n and (buf[i] == 45 or buf[i] == 43):
            eneg = buf[i] == 45
            i += 1
        edigits = 0
        e = 0
        while i < n and 48 <= buf[i] <= 57:
            if e < 100000:
                e = e * 10 + (buf[i] - 48)
            edigits += 1
            i += 1
        if edigits == 0:
            return 0.0, i, False
        exp10 += -e if eneg else e
    if i < n and not (_is_space(buf[i]) or buf[i] == 10):
        return 0.0, i, False  # junk glued to the number
    if mant == 0:
        v = 0.0
    elif mant < 9007199254740992 and -22 <= exp10 <= 22:
        # Both operands exact, so one IEEE operation rounds correctly (Clinger).
        v = mant * pow10[exp10] if exp10 >= 0 else mant / pow10[-exp10]
    else:
        half = exp10 // 2
        v = float(mant) * 10.0**half * 10.0 ** (exp10 - half)
    return -v if neg else v, i, True


@numba.njit(cache=True, nogil=True)
def parse_rows(buf, rows, cols, out, pow10):
    """Parse whitespace-separated numbers in `buf` (uint8) into `out` (rows*cols,),
    demanding exactly `cols` values on every non-blank line and exactly `rows` such
    lines. Returns (status, row, line, values on the failing row): line counts
    newlines from the start of buf (0-based)."""
    n = buf.size
    i = 0
    line = 0
    row = 0
    col = 0
    k = 0
    while i < n:
        c = buf[i]
        if c == 10:
            if col:
                if col != cols:
                    return ERR_COUNT, row, line, col
                row += 1
                col = 0
            line += 1
            i += 1
            continue
        if _is_space(c):
            i += 1
            continue
        if row >= rows:
            return ERR_EXTRA_ROWS, row, line, 0
        if col >= cols:
            return ERR_COUNT, row, line, col + 1
        v, i, ok = parse_number(buf, i, pow10)
        if not ok:
            return ERR_NUMBER, row, line, col
        out[k] = v
        k += 1
        col += 1
    if col:
        if col != cols:
            return ERR_COUNT, row, line, col
        row += 1
    if row != rows:
        return ERR_FEW_ROWS, row, line, 0
    return OK, row, line, 0


@numba.njit(cache=True, nogil=True)
def _channels_to_pose(values, joint, code, rot, trans, scale):
    """values (F, C) channel values in file order, degrees and file units; joint (C,)
    and code (C,) the channel's joint and kind. rot (F, J, 4) must start as identity
    and trans (F, J, 3) as the scaled offsets. Rotations compose in channel order,
    each new axis on the right (intrinsic), positions replace the offset."""
    F, C = values.shape
    half_rad = np.pi / 360.0
    for f in range(F):
        for c in range(C):
            j = joint[c]
            v = values[f, c]
            kind = code[c]
            if kind < 3:
                trans[f, j, kind] = v * scale
                continue
            h = v * half_rad
            s = np.sin(h)
            co = np.cos(h)
            w, x, y, z = rot[f, j, 0], rot[f, j, 1], rot[f, j, 2], rot[f, j, 3]
            # q ⊗ (cos, sin·axis)
            if kind == 3:
                rot[f, j, 0] = w * co - x * s
                rot[f, j, 1] = x * co + w * s
                rot[f, j, 2] = y * co + z * s
                rot[f, j, 3] = z * co - y * s
            elif kind == 4:
                rot[f, j, 0] = w * co - y * s
                rot[f, j, 1] = x * co - z * s
                rot[f, j, 2] = y * co + w * s
                rot[f, j, 3] = z * co + x * s
            else:
                rot[f, j, 0] = w * co - z * s
                rot[f, j, 1] = x * co + y * s
                rot[f, j, 2] = y * co - x * s
                rot[f, j, 3] = z * co + w * s


def parse_number_block(path, data: bytes, start: int, first_line: int, rows: int, cols: int) -> np.ndarray:
    """Numbers in data[start:] as a (rows, cols) array; FormatError naming the file
    line (1-based, data[start] lies on `first_line`) when the block is malformed."""
    buf = np.frombuffer(data, dtype=np.uint8, offset=start) if start < len(data) else np.zeros(0, np.uint8)
    out = np.empty(rows * cols)
    status, row, line, count = parse_rows(buf, rows, cols, out, _POW10)
    if status == OK:
        return out.reshape(rows, cols)
    lineno = first_line + line
    if status == ERR_COUNT:
        text = _line_text(buf, line)
        count = len(text.split())
        raise FormatError(path, f"frame {row}: expected {cols} values, found {count}", line=lineno)
    if status == ERR_NUMBER:
        bad = _line_text(buf, line).split()
        token = bad[count] if count < len(bad) else "?"
        raise FormatError(path, f"frame {row}: expected a number, found {token[:40]!r}", line=lineno)
    if status == ERR_EXTRA_ROWS:
        raise FormatError(path, f"more data rows than the {rows} frames declared (expected end of file)", line=lineno)
    raise FormatError(path, f"truncated: {rows} frames declared but only {row} data rows found", line=lineno)


def _line_text(buf: np.ndarray, line: int) -> str:
    """The `line`-th (0-based) line of buf as text, for error messages."""
    raw = buf.tobytes().split(b"\n")
    return raw[line].decode("utf-8", "replace") if line < len(raw) else ""


# ---------------------------------------------------------------------------
# Hierarchy
# ---------------------------------------------------------------------------

_TOKEN = re.compile(r"[{}]|[^\s{}]+")
_STRUCTURE = {"JOINT", "END", "OFFSET", "CHANNELS", "{", "}"}


class _Joints:
    """Joint table of a parsed hierarchy (plain lists; shared through the cache,
    so never mutated after parsing)."""

    def __init__(self):
        self.names: list[str] = []
        self.parents: list[int] = []
        self.offsets: list = []
        self.channels: list[tuple[str, ...]] = []
        self.end_site: list[bool] = []
        self.lines: list[int] = []


def _parse_hierarchy(path, header: str) -> _Joints:
    """Parse the HIERARCHY section (text before the MOTION line). One pass over a
    flat token list; every error names the line and what was expected there."""
    toks: list[str] = []
    lines: list[int] = []
    for lineno, text in enumerate(header.split("\n"), 1):
        found = _TOKEN.findall(text)
        toks.extend(found)
        lines.extend([lineno] * len(found))
    n = len(toks)
    end_line = header.count("\n") + 1

    def fail(i: int, message: str) -> NoReturn:
        raise FormatError(path, message, line=lines[i] if i < n else end_line)

    if n == 0 or toks[0].upper() != "HIERARCHY":
        fail(0, f"expected HIERARCHY at the start of the file, found {toks[0] if n else 'nothing'!r}")
    if n < 2 or toks[1].upper() != "ROOT":
        fail(1, f"expected ROOT after HIERARCHY, found {toks[1] if n > 1 else 'end of hierarchy'!r}")

    js = _Joints()
    names_seen: set[str] = set()

    def open_joint(i: int, parent: int, end_site: bool) -> int:
        """i: first token after ROOT/JOINT/Site. Returns the index after '{'."""
        line = lines[i - 1]
        start = i
        while i < n and lines[i] == line and toks[i] not in ("{", "}"):
            i += 1
        name = " ".join(toks[start:i])
        if end_site:
            name = name or f"{js.names[parent]}_End"
        elif not name:
            fail(i - 1, "expected a joint name after JOINT/ROOT")
        if name in names_seen:
            fail(i - 1, f"duplicate joint name {name!r}")
        if i >= n or toks[i] != "{":
            fail(i, f"expected '{{' opening joint {name!r}, found {toks[i] if i < n else 'end of hierarchy'!r}")
        names_seen.add(name)
        js.names.append(name)
        js.parents.append(parent)
        js.offsets.append(None)
        js.channels.append(())
        js.end_site.append(end_site)
        js.lines.append(line)
        stack.append(len(js.names) - 1)
        return i + 1

    stack: list[int] = []
    i = open_joint(2, -1, False)
    while stack:
        j = stack[-1]
        if i >= n:
            fail(i, f"unbalanced braces: expected '}}' closing joint {js.names[j]!r} (opened at line {js.lines[j]})")
        tok = toks[i]
        key = tok.upper()
        if key == "OFFSET":
            if js.offsets[j] is not None:
                fail(i, f"second OFFSET in joint {js.names[j]!r}")
            try:
                xyz = tuple(float(t) for t in toks[i + 1 : i + 4])
            except ValueError:
                xyz = ()
            if len(xyz) != 3 or not all(np.isfinite(xyz)) or len(set(lines[i : i + 4])) != 1:
                fail(i, f"expected OFFSET followed by 3 numbers in joint {js.names[j]!r}")
            js.offsets[j] = xyz
            i += 4
        elif key == "CHANNELS":
            if js.end_site[j]:
                fail(i, "an End Site has no CHANNELS")
            if js.channels[j]:
                fail(i, f"second CHANNELS line in joint {js.names[j]!r}")
            try:
                count = int(toks[i + 1])
            except (ValueError, IndexError):
                fail(i + 1, "expected a channel count after CHANNELS")
            if not 0 <= count <= 6:
                fail(i + 1, f"expected a channel count 0..6, found {count}")
            chan_line = lines[i]
            i += 2
            names = []
            while i < n and lines[i] == chan_line and toks[i].upper() not in _STRUCTURE:
                code = CHANNEL_CODES.get(toks[i].lower())
                if code is None:
                    fail(i, f"unknown channel name {toks[i]!r} (expected one of {', '.join(CHANNEL_NAMES)})")
                if CHANNEL_NAMES[code] in names:
                    fail(i, f"channel {toks[i]!r} listed twice")
                names.append(CHANNEL_NAMES[code])
                i += 1
            if len(names) != count:
                fail(i - 1, f"CHANNELS declares {count} channels but lists {len(names)}")
            js.channels[j] = tuple(names)
        elif key == "JOINT":
            if js.end_site[j]:
                fail(i, "an End Site cannot have child joints")
            i = open_joint(i + 1, j, False)
        elif key == "END":
            if js.end_site[j]:
                fail(i, "an End Site cannot have child joints")
            if i + 1 >= n or toks[i + 1].upper() != "SITE":
                fail(i + 1, "expected 'Site' after 'End'")
            i = open_joint(i + 2, j, True)
        elif tok == "}":
            if js.offsets[j] is None:
                fail(i, f"joint {js.names[j]!r} has no OFFSET")
            stack.pop()
            i += 1
        else:
            fail(i, f"expected OFFSET, CHANNELS, JOINT, End Site or '}}' in joint {js.names[j]!r}, found {tok!r}")
    if i < n:
        if toks[i].upper() == "ROOT":
            fail(i, "only one ROOT hierarchy is supported")
        fail(i, f"expected MOTION after the hierarchy, found {toks[i]!r}")
    return js


_HIERARCHY_CACHE: dict[bytes, _Joints] = {}
_HIERARCHY_CACHE_SIZE = 64


def _cached_hierarchy(path, header: bytes) -> _Joints:
    """Files of one capture session share their header byte for byte: parse once."""
    js = _HIERARCHY_CACHE.get(header)
    if js is None:
        try:
            text = header.decode("utf-8")
        except UnicodeDecodeError as exc:
            line = header[: exc.start].count(b"\n") + 1
            raise FormatError(path, "not UTF-8 text; expected a BVH hierarchy", line=line) from None
        js = _parse_hierarchy(path, text)
        if len(_HIERARCHY_CACHE) >= _HIERARCHY_CACHE_SIZE:
            _HIERARCHY_CACHE.pop(next(iter(_HIERARCHY_CACHE)))
        _HIERARCHY_CACHE[header] = js
    return js


# ---------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------

_MOTION = re.compile(rb"^[ \t]*MOTION[ \t]*\r?$", re.M)
_FRAMES = re.compile(rb"^[ \t]*Frames[ \t]*:[ \t]*(\S*)[ \t]*\r?$")
_FRAME_TIME = re.compile(rb"^[ \t]*Frame[ \t]+Time[ \t]*:[ \t]*(\S*)[ \t]*\r?$")


def read_file_bytes(path) -> bytes:
    """Whole file as bytes; the project's errors for a missing or unreadable file."""
    return read_input_bytes(path)


def _next_line(data: bytes, start: int, lineno: int) -> tuple[bytes, int, int]:
    """Next non-blank line at or after byte `start` (which begins line `lineno`):
    (line without EOL, line number, byte offset just past it)."""
    while start < len(data):
        end = data.find(b"\n", start)
        end = len(data) if end < 0 else end
        text = data[start:end]
        if text.strip():
            return text, lineno, end + 1
        start, lineno = end + 1, lineno + 1
    return b"", lineno, len(data)


def rate_from_frame_time(frame_time: float) -> float:
    """Frames per second, snapped to an integer when within 1e-3 (0.0333333 → 30)."""
    rate = 1.0 / frame_time
    nearest = round(rate)
    return float(nearest) if nearest > 0 and abs(rate - nearest) < 1e-3 else rate


def figure_size(parents: np.ndarray, bones: np.ndarray) -> float:
    """Longest path between two leaves along the bones (file units) — about the
    figure's height or arm span. bones: (J, 3) joint translations from the parent.
    The edge into a single-child root is left out: in files such as Bandai's it is a
    root-motion carrier (pelvis height plus travel), not a bone."""
    J = len(parents)
    length = np.linalg.norm(bones, axis=-1)
    down = np.zeros(J)  # longest path from joint j down to a leaf
    best = 0.0
    top = [[0.0, 0.0] for _ in range(J)]  # two longest child branches
    for j in range(J - 1, 0, -1):  # children after parents: reverse order is bottom-up
        down[j] = top[j][0]
        p = parents[j]
        branch = length[j] + down[j]
        t = top[p]
        if branch > t[0]:
            t[0], t[1] = branch, t[0]
        elif branch > t[1]:
            t[1] = branch
    for j in range(J):
        if j == 0 and int(np.sum(parents == 0)) == 1:
            continue
        best = max(best, top[j][0] + top[j][1])
    return best


def guess_scale(size: float) -> float:
    """File units → metres from a figure size in file units."""
    if size > MM_ABOVE:
        return 0.001
    if size > CM_ABOVE:
        return 0.01
    return 1.0


def read_bvh(path: StrPath, scale: float | None = None) -> Motion:
    """Read a BVH file into a Motion (local quaternions, translations in metres).

    scale: metres per file unit (0.01 for centimetres); None guesses it from the
    figure size (see `figure_size`, `guess_scale`). The rate is 1/Frame Time."""
    path = Path(path)
    data = read_file_bytes(path)
    m = _MOTION.search(data)
    if m is None:
        try:
            header = data.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise FormatError(path, f"not UTF-8 text (byte {exc.start}); expected a BVH file") from None
        _parse_hierarchy(path, header)  # a hierarchy error is the more precise message
        raise FormatError(path, "expected a MOTION section after the hierarchy", line=header.count("\n") + 1)
    head = data[: m.start()]
    js = _cached_hierarchy(path, head)
    motion_line = head.count(b"\n") + 1

    text, line, pos = _next_line(data, m.end() + 1, motion_line + 1)
    fm = _FRAMES.match(text)
    if fm is None:
        raise FormatError(path, "expected 'Frames: <count>' after MOTION", line=line)
    try:
        frames = int(fm.group(1))
    except ValueError:
        raise FormatError(path, f"expected an integer frame count, found {fm.group(1)[:40]!r}", line=line) from None
    if frames < 0:
        raise FormatError(path, f"expected a frame count ≥ 0, found {frames}", line=line)
    text, line, pos = _next_line(data, pos, line + 1)
    tm = _FRAME_TIME.match(text)
    if tm is None:
        raise FormatError(path, "expected 'Frame Time: <seconds>' after Frames", line=line)
    try:
        frame_time = float(tm.group(1))
    except ValueError:
        frame_time = float("nan")
    if not (np.isfinite(frame_time) and frame_time > 0 and np.isfinite(1.0 / frame_time)):
        raise FormatError(path, f"expected a positive Frame Time, found {tm.group(1)[:40]!r}", line=line)

    chan_joint = np.array([j for j, ch in enumerate(js.channels) for _ in ch], dtype=np.int64)
    chan_code = np.array([CHANNEL_CODES[c.lower()] for ch in js.channels for c in ch], dtype=np.int64)
    cols = len(chan_joint)
    # Every value takes at least two bytes (digit + separator): a larger frame count
    # cannot be honoured, so report truncation before allocating for it.
    room = len(data) - pos + 1
    if cols == 0:
        if data[pos:].strip():
            raise FormatError(path, "the hierarchy declares no channels but frame data follows", line=line + 1)
        if frames > data[pos:].count(b"\n") + 1:
            raise FormatError(path, f"truncated: {frames} frames declared but fewer lines follow", line=line + 1)
        values = np.zeros((frames, 0))
    elif frames * cols > room // 2:
        last = line + data[pos:].count(b"\n")
        raise FormatError(path, f"truncated: {frames} frames declared but the data holds fewer", line=last)
    else:
        values = parse_number_block(path, data, pos, line + 1, frames, cols)
    if frames == 0:
        raise InputError(f"{path}: motion has zero frames")
    bad = ~np.isfinite(values)
    if bad.any():
        f = int(np.nonzero(bad.any(axis=1))[0][0])
        raise InputError(f"{path}: frame {f} has a NaN or infinite value")

    offsets = np.array(js.offsets, dtype=np.float64)
    parents = np.array(js.parents, dtype=np.int64)
    if scale is None:
        first = np.broadcast_to(offsets, offsets.shape).copy()
        for c, (j, code) in enumerate(zip(chan_joint, chan_code)):
            if code < 3:
                first[j, code] = values[0, c]  # position channels replace the offset
        scale = guess_scale(figure_size(parents, first))
    scale = float(scale)
    if not (np.isfinite(scale) and scale > 0):
        raise InputError(f"scale must be positive and finite, got {scale}")

    J = len(js.names)
    rot = np.zeros((frames, J, 4))
    rot[..., 0] = 1.0
    trans = np.empty((frames, J, 3))
    trans[:] = offsets * scale
    _channels_to_pose(values, chan_joint, chan_code, rot, trans, scale)
    skeleton = Skeleton(
        names=tuple(js.names),
        parents=parents,
        offsets=offsets * scale,
        channels=tuple(js.channels),
        end_site=np.array(js.end_site, dtype=bool),
    )
    return Motion(skeleton, rot, trans, rate_from_frame_time(frame_time), name=path.stem, source=str(path))


# ---------------------------------------------------------------------------
# Writing
# ---------------------------------------------------------------------------

_FMT = "%.9g"  # 9 significant digits: 1e-6 degree / sub-micrometre round trips


def _num(v: float) -> str:
    return _FMT % (float(v) + 0.0)  # + 0.0 turns -0.0 into 0.0


def channel_values(motion: Motion, scale: float = 1.0) -> np.ndarray:
    """(F, C) BVH channel values in file order: positions in file units (metres ×
    scale), rotations in degrees from each joint's own rotation channel order."""
    sk = motion.skeleton
    cols = []
    for j, ch in enumerate(sk.channels):
        if not ch:
            continue
        rot_order = "".join(c[0] for c in ch if c.endswith("rotation")).upper()
        euler = quat.to_euler(motion.rotations[:, j], rot_order, degrees=True) if rot_order else np.zeros((0, 0))
        r = 0
        for c in ch:
            if c.endswith("position"):
                cols.append(motion.translations[:, j, "XYZ".index(c[0].upper())] * scale)
            else:
                cols.append(euler[:, r])
                r += 1
    if not cols:
        return np.zeros((motion.num_frames, 0))
    return np.stack(cols, axis=1)


def bvh_text(motion: Motion, scale: float = 1.0) -> str:
    """The BVH file text of `motion` (scale: file units per metre)."""
    sk = motion.skeleton
    children: list[list[int]] = [[] for _ in range(sk.num_joints)]
    for j in range(1, sk.num_joints):
        children[sk.parents[j]].append(j)
    out: list[str] = ["HIERARCHY"]

    def emit(j: int, depth: int):
        ind = "  " * depth
        off = " ".join(_num(v) for v in sk.offsets[j] * scale)
        if sk.end_site[j]:
            default = f"{sk.names[sk.parents[j]]}_End"
            out.append(f"{ind}End Site" + ("" if sk.names[j] == default else f" {sk.names[j]}"))
            out.append(f"{ind}{{")
            out.append(f"{ind}  OFFSET {off}")
            out.append(f"{ind}}}")
            return
        out.append(f"{ind}{'ROOT' if depth == 0 else 'JOINT'} {sk.names[j]}")
        out.append(f"{ind}{{")
        out.append(f"{ind}  OFFSET {off}")
        out.append(f"{ind}  CHANNELS {len(sk.channels[j])}" + "".join(" " + c for c in sk.channels[j]))
        for c in children[j]:
            emit(c, depth + 1)
        out.append(f"{ind}}}")

    emit(0, 0)
    out.append("MOTION")
    out.append(f"Frames: {motion.num_frames}")
    out.append(f"Frame Time: {_num(1.0 / motion.rate_hz)}")
    values = channel_values(motion, scale) + 0.0
    row = " ".join([_FMT] * values.shape[1])
    out.extend(row % tuple(v) for v in values.tolist())
    return "\n".join(out) + "\n"


def write_bvh(path: StrPath, motion: Motion, scale: float = 1.0) -> None:
    """Write `motion` as BVH, atomically (temp file beside `path`, then rename).
    scale: file units per metre (100 → centimetres). Channels keep the skeleton's
    order; a joint without rotation channels is written unrotated and a joint
    without position channels at its rest offset."""
    write_text_atomic(path, bvh_document(motion, scale))


def bvh_document(motion: Motion, scale: float = 1.0) -> str:
    """The text `write_bvh` writes; InputError for a scale or joint names BVH cannot hold."""
    if not (np.isfinite(scale) and scale > 0):
        raise InputError(f"scale must be positive and finite, got {scale}")
    # The reader takes a name as the rest of its line, words joined by one space.
    bad = [n for n in motion.skeleton.names if not n or " ".join(n.split()) != n or re.search(r"[{}]", n)]
    if bad:
        raise InputError(f"joint names cannot be written to BVH: {bad[:5]}")
    return bvh_text(motion, scale)
