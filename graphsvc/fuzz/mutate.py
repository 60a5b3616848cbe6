"""Mutations of an input: byte-level ones any format gets (bit flips, byte values,
truncation, deletion, duplication, splices with another corpus entry, numbers in the
text replaced by extreme ones) and a protobuf one that sets a random field of a
decoded message to a hostile value. All driven by a `random.Random`, so a run is
reproducible from its seed."""

from __future__ import annotations

import random
import re

# Numbers that break parsers: zero, signs, the integer and float limits, huge counts
# (a declared size that must be refused before anything is allocated), non-finite.
INTERESTING_NUMBERS = (
    b"0",
    b"-0",
    b"1",
    b"-1",
    b"2",
    b"255",
    b"65535",
    b"65536",
    b"2147483647",
    b"-2147483648",
    b"4294967296",
    b"9223372036854775807",
    b"18446744073709551616",
    b"1000000000000",
    b"1e308",
    b"1e309",
    b"-1e308",
    b"5e-324",
    b"1e-320",
    b"nan",
    b"inf",
    b"-inf",
    b"NaN",
    b"0.000000001",
    b"1.5",
    b"99999999999999999999999",
    b"0x10",
    b"1_000",
)
_NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
_INTERESTING_INTS = (
    0,
    1,
    2,
    3,
    4,
    7,
    8,
    16,
    64,
    127,
    128,
    255,
    256,
    512,
    1024,
    4096,
    32767,
    32768,
    65535,
    65536,
    0x7FFFFFFF,
    0x80000000,
    0xFFFFFFFF,
)


def _flip_bit(data: bytearray, rng: random.Random, corpus) -> None:
    if data:
        i = rng.randrange(len(data))
        data[i] ^= 1 << rng.randrange(8)


def _set_byte(data: bytearray, rng: random.Random, corpus) -> None:
    if data:
        data[rng.randrange(len(data))] = rng.choice(
            (0, 0xFF, 0x7F, 0x80, 10, 13, 32, 34, 44, 123, 125, rng.randrange(256))
        )


def _set_int(data: bytearray, rng: random.Random, corpus) -> None:
    """A 1/2/4/8-byte little- or big-endian integer field overwritten (binary headers)."""
    width = rng.choice((1, 2, 4, 8))
    if len(data) < width:
        return
    i = rng.randrange(len(data) - width + 1)
    value = rng.choice(_INTERESTING_INTS) if rng.random() < 0.8 else rng.getrandbits(8 * width)
    value = (value + rng.choice((0, 0, -1, 1))) % (1 << (8 * width))
    data[i : i + width] = value.to_bytes(width, rng.choice(("little", "big")))


def _truncate(data: bytearray, rng: random.Random, corpus) -> None:
    if data:
        del data[rng.randrange(len(data)) :]


def _delete(data: bytearray, rng: random.Random, corpus) -> None:
    if data:
        i = rng.randrange(len(data))
        del data[i : i + rng.choice((1, 2, 4, 16, 64, 512))]


def _duplicate(data: bytearray, rng: random.Random, corpus) -> None:
    if data:
        i = rng.randrange(len(data))
        chunk = data[i : i + rng.choice((1, 4, 16, 64, 512))]
        j = rng.randrange(len(data) + 1)
        data[j:j] = chunk * rng.choice((1, 1, 2, 8))


def _line_op(data: bytearray, rng: random.Random, corpus) -> None:
    """A whole line deleted, duplicated or swapped with another (text formats)."""
    lines = bytes(data).split(b"\n")
    if len(lines) < 2:
        return
    i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
    op = rng.randrange(3)
    if op == 0:
        del lines[i]
    elif op == 1:
        lines.insert(j, lines[i])
    else:
        lines[i], lines[j] = lines[j], lines[i]
    data[:] = b"\n".join(lines)


def _splice(data: bytearray, rng: random.Random, corpus) -> None:
    """The head of this input joined to the tail of another corpus entry."""
    if not corpus:
        return
    other = rng.choice(corpus)
    i = rng.randrange(len(data) + 1)
    j = rng.randrange(len(other) + 1)
    data[i:] = other[j:]


def _number(data: bytearray, rng: random.Random, corpus) -> None:
    """A number in the text replaced by an extreme one, or nudged."""
    found = list(_NUMBER.finditer(bytes(data)))
    if not found:
        return
    m = rng.choice(found)
    if rng.random() < 0.7:
        new = rng.choice(INTERESTING_NUMBERS)
    else:
        try:
            new = repr(float(m.group()) * rng.choice((-1, 0.5, 2, 10, 1e6)) + rng.choice((0, 1, -1))).encode()
        except (ValueError, OverflowError):
            new = b"0"
    data[m.start() : m.end()] = new


def _insert_token(data: bytearray, rng: random.Random, corpus) -> None:
    token = rng.choice(
        (
            b"\x00",
            b"\xff\xfe",
            b"\r\n",
            b"\n",
            b" ",
            b",",
            b";",
            b"#",
            b'"',
            b"{",
            b"}",
            b"[",
            b"]",
            b"<",
            b"&amp;",
            b"\xc3",
            b"\xe2\x82\xac",
            b"nan",
            b"1e999",
            b"-",
            b"Frames: 2",
            b"<!DOCTYPE a [<!ENTITY x 'xx'>]>",
            b"End Site",
            b"JOINT",
            b":",
            b"=",
            b"\t",
        )
    )
    i = rng.randrange(len(data) + 1)
    data[i:i] = token


MUTATORS = (
    _flip_bit,
    _set_byte,
    _set_int,
    _truncate,
    _delete,
    _duplicate,
    _line_op,
    _splice,
    _number,
    _number,
    _insert_token,
)


def mutate(data: bytes, rng: random.Random, corpus=(), structured=None, max_size: int = 1 << 20) -> bytes:
    """One to four stacked mutations of `data` (with `structured`, the target's own
    mutator, a third of the time); the result is kept under `max_size` bytes."""
    if structured is not None and rng.random() < 1 / 3:
        out = structured(data, rng)
        return out[:max_size]
    buf = bytearray(data)
    for _ in range(rng.choice((1, 1, 1, 2, 2, 3, 4))):
        rng.choice(MUTATORS)(buf, rng, corpus)
    return bytes(buf[:max_size])


# ---------------------------------------------------------------- protobuf messages

_HOSTILE_FLOATS = (
    float("nan"),
    float("inf"),
    float("-inf"),
    0.0,
    -0.0,
    -1.0,
    1e308,
    -1e308,
    5e-324,
    1e-9,
    3.4e38,
    1e12,
    0.5,
    30.0,
    4096.0,
)
_HOSTILE_INTS = (0, -1, 1, 2, 3, 4, 5, 257, 2**31 - 1, -(2**31), 2**63 - 1, -(2**63))
_HOSTILE_STRINGS = (
    "",
    " ",
    "a",
    "l_forearm",
    "lower_back",
    "LWRA",
    "a,b",
    'q"',
    "x\n",
    "\x00",
    " pad ",
    "{",
    "{}",
    '{"markers": []}',
    '{"markers": [{"name": "A", "segment": "head"}]}',
    "hands-feet",
    "vicon",
    "fit",
    "nominal",
    "walk",
    "é" * 3,
    "x" * 5000,
)


def _fields(msg, out: list, depth: int = 0) -> list:
    """(message, field descriptor) of every field reachable from msg (set or not)."""
    for fd in msg.DESCRIPTOR.fields:
        out.append((msg, fd))
        if fd.message_type is not None and not fd.is_repeated and depth < 4:
            if msg.HasField(fd.name) or depth < 2:
                _fields(getattr(msg, fd.name), out, depth + 1)
        elif fd.message_type is not None and depth < 4:
            children = getattr(msg, fd.name)
            if fd.message_type.GetOptions().map_entry:  # (a map, a Struct's fields: its values)
                children = children.values() if fd.message_type.fields_by_name["value"].message_type else ()
            for child in list(children)[:3]:
                _fields(child, out, depth + 1)
    return out


def _hostile(fd, rng: random.Random):
    t = fd.type
    if t in (fd.TYPE_DOUBLE, fd.TYPE_FLOAT):
        return rng.choice(_HOSTILE_FLOATS) if rng.random() < 0.8 else rng.uniform(-100, 100)
    if t == fd.TYPE_BOOL:
        return rng.random() < 0.5
    if t == fd.TYPE_STRING:
        return rng.choice(_HOSTILE_STRINGS)
    if t == fd.TYPE_BYTES:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(16)))
    if t == fd.TYPE_ENUM:
        return rng.choice([v.number for v in fd.enum_type.values] + [-1, 99])
    value = rng.choice(_HOSTILE_INTS)
    if t in (fd.TYPE_UINT32, fd.TYPE_FIXED32):
        return value % 2**32
    if t in (fd.TYPE_UINT64, fd.TYPE_FIXED64):
        return value % 2**64
    if t in (fd.TYPE_INT32, fd.TYPE_SINT32, fd.TYPE_SFIXED32):
        return max(-(2**31), min(2**31 - 1, value))
    return value


_HOSTILE_KEYS = (
    "k",
    "m",
    "i",
    "beam",
    "markers",
    "keep",
    "window_s",
    "overlap_s",
    "offsets",
    "track_pull_s",
    "extended",
    "w_prior",
    "",
    "nope",
    "x" * 200,
)


def _mutate_map(entries, entry_type, rng: random.Random) -> None:
    """A map field (a Struct's fields): an entry removed, or one set to a hostile
    key and value (for a Struct: a number, a flag, a text, a list, a null)."""
    if len(entries) and rng.random() < 0.3:
        del entries[rng.choice(list(entries))]
        return
    key = rng.choice(_HOSTILE_KEYS)
    value_fd = entry_type.fields_by_name["value"]
    if value_fd.message_type is None:
        entries[key] = _hostile(value_fd, rng)
        return
    value = entries[key]  # (a Value: one of its kinds)
    kind = rng.randrange(5)
    if kind == 0:
        value.number_value = rng.choice(_HOSTILE_FLOATS)
    elif kind == 1:
        value.bool_value = rng.random() < 0.5
    elif kind == 2:
        value.string_value = rng.choice(_HOSTILE_STRINGS)
    elif kind == 3:
        value.list_value.values.add().string_value = rng.choice(_HOSTILE_STRINGS)
    else:
        value.null_value = 0


def mutate_message(msg, rng: random.Random) -> None:
    """Set one reachable field of `msg` to a hostile value: a scalar to an extreme or
    non-finite one, a repeated field cleared, cut, lengthened (up to 100,000 values) or
    given a hostile element, a message cleared or filled."""
    fields = _fields(msg, [])
    if not fields:
        return
    parent, fd = rng.choice(fields)
    if fd.message_type is not None and fd.message_type.GetOptions().map_entry:
        _mutate_map(getattr(parent, fd.name), fd.message_type, rng)
    elif fd.is_repeated:
        values = getattr(parent, fd.name)
        op = rng.randrange(5)
        if op == 0:
            parent.ClearField(fd.name)
        elif fd.message_type is not None:
            if op == 1 and len(values):
                del values[rng.randrange(len(values)) :]
            else:
                child = values.add()
                if rng.random() < 0.7:
                    for grand, gfd in _fields(child, [])[:6]:
                        if gfd.message_type is None and not gfd.is_repeated:
                            setattr(grand, gfd.name, _hostile(gfd, rng))
        elif op == 1 and len(values):
            del values[rng.randrange(len(values)) :]
        elif op == 2:
            values.extend([_hostile(fd, rng)] * rng.choice((1, 2, 3, 7, 100, 100_000)))
        elif len(values):
            values[rng.randrange(len(values))] = _hostile(fd, rng)
        else:
            values.append(_hostile(fd, rng))
    elif fd.message_type is not None:
        if rng.random() < 0.5:
            parent.ClearField(fd.name)
        else:
            getattr(parent, fd.name).SetInParent()
    else:
        setattr(parent, fd.name, _hostile(fd, rng))
