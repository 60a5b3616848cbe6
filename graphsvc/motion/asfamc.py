"""Acclaim ASF (skeleton) and AMC (motion) reading, as used by the CMU database.

Conversion to the BVH-like model of skeleton.py: every ASF bone b becomes a joint
at the START of b, named b; a leaf bone also gets an end-site joint `<b>_End` at its
end. With C_b the bone's `axis` rotation and M_b its AMC rotation (both composed
about fixed axes in the listed order, first listed applied first), the Acclaim
world orientation of a bone is W_b = W_parent · C_b · M_b · C_b⁻¹ and the bone ends
at start + W_b · direction_b · length_b. Taking joint rotation = W_b makes the local
rotation C_b · M_b · C_b⁻¹ and the child joints' translation direction_b · length_b,
so our forward kinematics reproduces the Acclaim positions exactly.

Units: `:units length L` means 1 file unit = (1/L) inches; `angle deg|rad` applies
to the ASF and, unless the AMC says :DEGREES/:RADIANS, to the AMC as well.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from graphsvc.errors import FormatError, InputError
from graphsvc.fileio import require_file
from graphsvc.motion import quat
from graphsvc.motion.bvh import _POW10, ERR_COUNT, ERR_NUMBER, OK, _channels_to_pose, parse_rows, read_file_bytes
from graphsvc.motion.skeleton import Motion, Skeleton

INCH = 0.0254  # metres
CMU_RATE_HZ = 120.0
BONE_DOFS = ("rx", "ry", "rz", "tx", "ty", "tz", "l")
ROOT_DOFS = ("tx", "ty", "tz", "rx", "ry", "rz")
_ROT_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")
_POS_CHANNELS = ("Xposition", "Yposition", "Zposition")


@dataclass(frozen=True)
class AsfBone:
    """One ASF bone, in file units: direction (3,) unit vector in the rest pose,
    length, axis (3,) angles in radians composed in `axis_order` (fixed axes),
    dof: AMC value order (subset of rx ry rz tx ty tz l)."""

    name: str
    direction: np.ndarray
    length: float
    axis: np.ndarray
    axis_order: str
    dof: tuple[str, ...]
    line: int


@dataclass(frozen=True)
class AsfSkeleton:
    """A parsed ASF file. metres_per_unit converts lengths; angles are radians.
    root_order: AMC root value order; children: parent name → child bone names
    ("root" included) in :hierarchy order."""

    path: str
    name: str
    metres_per_unit: float
    angle_in_degrees: bool
    root_order: tuple[str, ...]
    root_axis: str
    root_position: np.ndarray
    root_orientation: np.ndarray
    bones: dict[str, AsfBone]
    children: dict[str, tuple[str, ...]]


# ---------------------------------------------------------------------------
# Text helpers
# ---------------------------------------------------------------------------


def _check_utf8_outside_comments(path, data: bytes) -> None:
    """FormatError unless every line but `#` comments is UTF-8: Vicon's exporters write
    the source file's path into an AMC's first comment in the local code page (HDM05's
    takes: `f\xfcr Bonn` in Latin-1), and comments are never read."""
    try:
        data.decode("utf-8")
        return
    except UnicodeDecodeError:
        pass
    for number, line in enumerate(data.split(b"\n"), start=1):
        if line.lstrip().startswith(b"#"):
            continue
        try:
            line.decode("utf-8")
        except UnicodeDecodeError:
            raise FormatError(path, "not UTF-8 text", line=number) from None


def _text_lines(path, data: bytes) -> list[str]:
    """File lines with CRLF handled and comments stripped (line i is file line i+1)."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise FormatError(path, "not UTF-8 text", line=line) from None
    if "\x00" in text:
        raise FormatError(
            path, "binary data (NUL byte) in a text file", line=text[: text.index("\x00")].count("\n") + 1
        )
    return [ln.split("#", 1)[0] for ln in text.replace("\r\n", "\n").replace("\r", "\n").split("\n")]


def _floats(path, words: list[str], count: int, what: str, line: int) -> np.ndarray:
    if len(words) != count:
        raise FormatError(path, f"expected {count} numbers for {what}, found {len(words)}", line=line)
    try:
        out = np.array([float(w) for w in words])
    except ValueError:
        raise FormatError(
            path, f"expected {count} numbers for {what}, found {' '.join(words)[:60]!r}", line=line
        ) from None
    if not np.all(np.isfinite(out)):
        raise FormatError(path, f"expected finite numbers for {what}", line=line)
    return out


def _axis_order(path, word: str, line: int) -> str:
    order = word.upper()
    if len(order) != 3 or set(order) != set("XYZ"):
        raise FormatError(path, f"expected an axis order such as XYZ, found {word!r}", line=line)
    return order


def fixed_axes_quat(angles: np.ndarray, axes: str) -> np.ndarray:
    """Rotations about fixed axes applied in the order listed (first listed first):
    angles (..., k) radians, axes a k-letter string of X/Y/Z → (..., 4). "XYZ" is
    R = Rz·Ry·Rx, i.e. quat.from_euler(angles[..., ::-1], "ZYX")."""
    angles = np.asarray(angles, dtype=float)
    q = quat.identity(angles.shape[:-1])
    for k, a in enumerate(axes.upper()):
        half = 0.5 * angles[..., k]
        e = np.zeros(angles.shape[:-1] + (4,))
        e[..., 0] = np.cos(half)
        e[..., 1 + "XYZ".index(a)] = np.sin(half)
        q = quat.mul(e, q)
    return q


# ---------------------------------------------------------------------------
# ASF
# ---------------------------------------------------------------------------


def read_asf(path) -> AsfSkeleton:
    """Parse an ASF skeleton file. FormatError names the line of any problem."""
    path = Path(path)
    lines = _text_lines(path, read_file_bytes(path))
    units = {"length": 1.0, "angle": "deg"}
    root = {"order": ROOT_DOFS, "axis": "XYZ", "position": np.zeros(3), "orientation": np.zeros(3)}
    bones_raw: list[dict] = []
    hierarchy: list[tuple[int, list[str]]] = []
    name = ""
    section = None
    seen: set[str] = set()
    bone: dict | None = None
    in_hierarchy_block = False

    for i, raw in enumerate(lines):
        ln = i + 1
        words = raw.replace(",", " ").replace("(", " ").replace(")", " ").split()
        if not words:
            continue
        if words[0].startswith(":"):
            if bone is not None:
                raise FormatError(path, f"bone {bone.get('name', '?')!r} lacks 'end'", line=ln)
            section = words[0][1:].lower()
            seen.add(section)
            if section == "name":
                name = " ".join(words[1:])
            continue
        key = words[0].lower()
        if section == "units":
            if key == "length":
                v = _floats(path, words[1:], 1, "units length", ln)[0]
                if v <= 0:
                    raise FormatError(path, "expected a positive units length", line=ln)
                units["length"] = v
            elif key == "angle":
                if len(words) != 2 or words[1].lower() not in ("deg", "rad"):
                    raise FormatError(path, "expected 'angle deg' or 'angle rad'", line=ln)
                units["angle"] = words[1].lower()
        elif section == "root":
            if key == "order":
                order = tuple(w.lower() for w in words[1:])
                bad = [w for w in order if w not in ROOT_DOFS]
                if bad or len(set(order)) != len(order):
                    raise FormatError(
                        path,
                        f"expected root order tokens from {' '.join(ROOT_DOFS)}, found {' '.join(words[1:])!r}",
                        line=ln,
                    )
                root["order"] = order
            elif key == "axis":
                if len(words) != 2:
                    raise FormatError(path, "expected 'axis' followed by an order such as XYZ", line=ln)
                root["axis"] = _axis_order(path, words[1], ln)
            elif key in ("position", "orientation"):
                root[key] = _floats(path, words[1:], 3, f"root {key}", ln)
        elif section == "bonedata":
            if key == "begin":
                if bone is not None:
                    raise FormatError(path, "expected 'end' before the next 'begin'", line=ln)
                bone = {"line": ln}
            elif key == "end":
                if bone is None:
                    raise FormatError(path, "'end' without 'begin'", line=ln)
                for need in ("name", "direction", "length"):
                    if need not in bone:
                        raise FormatError(path, f"bone starting at line {bone['line']} lacks '{need}'", line=ln)
                bones_raw.append(bone)
                bone = None
            elif bone is None:
                raise FormatError(path, f"expected 'begin' in :bonedata, found {words[0]!r}", line=ln)
            elif key == "id":
                pass
            elif key == "name":
                if len(words) != 2:
                    raise FormatError(path, "expected 'name <bone>'", line=ln)
                bone["name"] = words[1]
            elif key == "direction":
                bone["direction"] = _floats(path, words[1:], 3, "direction", ln)
            elif key == "length":
                bone["length"] = float(_floats(path, words[1:], 1, "length", ln)[0])
            elif key == "axis":
                if len(words) != 5:
                    raise FormatError(path, "expected 'axis <a> <b> <c> <order>'", line=ln)
                bone["axis"] = _floats(path, words[1:4], 3, "axis", ln)
                bone["axis_order"] = _axis_order(path, words[4], ln)
            elif key == "dof":
                dof = tuple(w.lower() for w in words[1:])
                bad = [w for w in dof if w not in BONE_DOFS]
                if bad or len(set(dof)) != len(dof):
                    raise FormatError(
                        path, f"expected dof tokens from {' '.join(BONE_DOFS)}, found {' '.join(words[1:])!r}", line=ln
                    )
                bone["dof"] = dof
            # limits (and their continuation lines), bodymass, cofmass: not needed
        elif section == "hierarchy":
            if key == "begin":
                in_hierarchy_block = True
            elif key == "end":
                in_hierarchy_block = False
            elif not in_hierarchy_block:
                raise FormatError(path, f"expected 'begin' in :hierarchy, found {words[0]!r}", line=ln)
            else:
                hierarchy.append((ln, words))
    if bone is not None:
        raise FormatError(path, f"bone starting at line {bone['line']} lacks 'end'", line=len(lines))
    if "bonedata" not in seen:
        raise FormatError(path, "expected a :bonedata section", line=len(lines))
    if "hierarchy" not in seen:
        raise FormatError(path, "expected a :hierarchy section", line=len(lines))

    metres = INCH / units["length"]
    to_rad = np.pi / 180.0 if units["angle"] == "deg" else 1.0
    bones: dict[str, AsfBone] = {}
    for b in bones_raw:
        if b["name"] in bones or b["name"] == "root":
            raise FormatError(path, f"duplicate bone name {b['name']!r}", line=b["line"])
        d = b["direction"]
        norm = np.linalg.norm(d)
        if b["length"] < 0 or (norm == 0 and b["length"] > 0):
            raise FormatError(path, f"bone {b['name']!r}: expected a non-zero direction and length ≥ 0", line=b["line"])
        bones[b["name"]] = AsfBone(
            name=b["name"],
            direction=d / norm if norm > 0 else d,
            length=b["length"],
            axis=b.get("axis", np.zeros(3)) * to_rad,
            axis_order=b.get("axis_order", "XYZ"),
            dof=b.get("dof", ()),
            line=b["line"],
        )

    children: dict[str, list[str]] = {"root": []}
    parent_of: dict[str, str] = {}
    for ln, words in hierarchy:
        parent = words[0]
        if parent != "root" and parent not in bones:
            raise FormatError(path, f"unknown bone {parent!r} in :hierarchy", line=ln)
        for child in words[1:]:
            if child not in bones:
                raise FormatError(path, f"unknown bone {child!r} in :hierarchy", line=ln)
            if child in parent_of:
                raise FormatError(path, f"bone {child!r} has two parents in :hierarchy", line=ln)
            parent_of[child] = parent
            children.setdefault(parent, []).append(child)
    # Every bone must hang from root (this also rules out cycles).
    reached, todo = set(), ["root"]
    while todo:
        p = todo.pop()
        for c in children.get(p, []):
            reached.add(c)
            todo.append(c)
    missing = [b for b in bones if b not in reached]
    if missing:
        raise FormatError(
            path, f"bones not connected to root in :hierarchy: {', '.join(missing[:5])}", line=bones[missing[0]].line
        )

    return AsfSkeleton(
        path=str(path),
        name=name,
        metres_per_unit=metres,
        angle_in_degrees=units["angle"] == "deg",
        root_order=tuple(root["order"]),
        root_axis=root["axis"],
        root_position=root["position"],
        root_orientation=root["orientation"] * to_rad,
        bones=bones,
        children={k: tuple(v) for k, v in children.items()},
    )


def joint_order(asf: AsfSkeleton) -> list[tuple[str, str | None, str]]:
    """(joint name, bone it belongs to or None for root, kind) in depth-first order:
    kind is "root", "bone" (joint at the bone's start) or "end" (leaf bone's end)."""
    out = [("root", None, "root")]

    def visit(b: str):
        out.append((b, b, "bone"))
        kids = asf.children.get(b, ())
        if not kids:
            out.append((f"{b}_End", b, "end"))
        for c in kids:
            visit(c)

    for c in asf.children.get("root", ()):
        visit(c)
    return out


# ---------------------------------------------------------------------------
# AMC
# ---------------------------------------------------------------------------

_INT = re.compile(rb"^[ \t]*([0-9]{1,12})[ \t\r]*$")


def _amc_header(path, data: bytes) -> tuple[int, int, bool | None]:
    """(byte offset of the first frame-number line, its 1-based line, degrees flag
    from :DEGREES/:RADIANS or None)."""
    pos, line, degrees = 0, 1, None
    while pos < len(data):
        end = data.find(b"\n", pos)
        end = len(data) if end < 0 else end
        text = data[pos:end].strip()
        if text and not text.startswith(b"#"):
            if not text.startswith(b":"):
                return pos, line, degrees
            key = text.upper()
            if key.startswith(b":DEG"):
                degrees = True
            elif key.startswith(b":RAD"):
                degrees = False
        pos, line = end + 1, line + 1
    return len(data), line, degrees


def _amc_layout(asf: AsfSkeleton) -> dict[str, int]:
    """AMC line name → value count, for every bone that appears in an AMC frame."""
    out = {"root": len(asf.root_order)}
    out.update({b.name: len(b.dof) for b in asf.bones.values() if b.dof})
    return out


def _parse_amc_fast(path, data: bytes, start: int, first_line: int, counts: dict[str, int]):
    """Fast path for the usual layout (every frame lists the same lines in the same
    order, no blank lines): columns of lines are checked with list slicing and the
    numbers go through the compiled row parser. Returns (names, {name: (F, k)}) or
    None when the layout is irregular (the general parser then reports errors)."""
    lines = data[start:].split(b"\n")
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        return [], {}
    first = _INT.match(lines[0])
    if first is None:
        return None
    names = []
    for ln in lines[1:]:
        if _INT.match(ln):
            break
        names.append(ln.split(None, 1)[0].decode("utf-8", "replace") if ln.strip() else "")
    if not names or any(n not in counts for n in names) or len(set(names)) != len(names):
        return None
    if set(names) != set(counts):
        return None
    stride = 1 + len(names)
    if len(lines) % stride:
        return None
    frames = len(lines) // stride
    f0 = int(first.group(1))
    try:
        numbers = [int(x) for x in lines[0::stride]]
    except ValueError:
        return None
    if numbers != list(range(f0, f0 + frames)):
        return None
    out = {}
    for s, name in enumerate(names):
        col = lines[1 + s :: stride]
        # Every line of the column must start with "<name> ": count the prefixes in
        # one joined buffer (C speed), then blank them out for the number parser.
        block = b"\n" + b"\n".join(col)
        prefix = b"\n" + name.encode() + b" "
        if block.count(prefix) != frames:
            return None
        block = block.replace(prefix, b"\n ")
        buf = np.frombuffer(block, dtype=np.uint8)
        k = counts[name]
        vals = np.empty(frames * k)
        status, row, _, _ = parse_rows(buf, frames, k, vals, _POW10)
        if status != OK:
            ln = first_line + row * stride + 1 + s
            if status == ERR_COUNT:
                found = len(col[row].split()) - 1
                raise FormatError(path, f"frame {f0 + row}: bone {name!r} expected {k} values, found {found}", line=ln)
            if status == ERR_NUMBER:
                raise FormatError(path, f"frame {f0 + row}: bone {name!r} expected {k} numbers", line=ln)
            return None
        out[name] = vals.reshape(frames, k)
    return names, out


def _parse_amc_general(path, data: bytes, start: int, first_line: int, counts: dict[str, int]):
    """Line-by-line AMC parser: any line order within a frame, blank lines allowed.
    Slow but precise; used when the fast path declines."""
    text = data[start:].decode("utf-8", "replace").replace("\r", "")
    rows: dict[str, list[list[float]]] = {n: [] for n in counts}
    frame = None
    f0 = None
    present: set[str] = set()
    last_line = first_line

    def close(ln: int):
        missing = [n for n in counts if n not in present]
        if missing:
            raise FormatError(path, f"frame {frame} is truncated: expected bone {missing[0]!r}", line=ln)

    for i, raw in enumerate(text.split("\n")):
        ln = first_line + i
        words = raw.split()
        if not words or words[0].startswith("#"):
            continue
        last_line = ln
        if len(words) == 1 and re.fullmatch(r"[0-9]{1,12}", words[0]):
            number = int(words[0])
            if frame is not None:
                close(ln)
                if number != frame + 1:
                    raise FormatError(path, f"expected frame number {frame + 1}, found {number}", line=ln)
            f0 = number if f0 is None else f0
            frame = number
            present = set()
            continue
        if frame is None:
            raise FormatError(path, f"expected a frame number, found {raw.strip()[:40]!r}", line=ln)
        name = words[0]
        if name not in counts:
            raise FormatError(path, f"frame {frame}: unknown bone {name!r} (not in the ASF, or it has no dof)", line=ln)
        if name in present:
            raise FormatError(path, f"frame {frame}: bone {name!r} listed twice", line=ln)
        k = counts[name]
        if len(words) - 1 != k:
            raise FormatError(
                path, f"frame {frame}: bone {name!r} expected {k} values, found {len(words) - 1}", line=ln
            )
        try:
            rows[name].append([float(w) for w in words[1:]])
        except ValueError:
            raise FormatError(path, f"frame {frame}: bone {name!r} expected {k} numbers", line=ln) from None
        present.add(name)
    if frame is not None:
        close(last_line + 1)
    names = list(counts)
    return names, {n: np.array(rows[n], dtype=float).reshape(-1, counts[n]) for n in names}


def read_amc(path, asf: AsfSkeleton, rate_hz: float = CMU_RATE_HZ) -> Motion:
    """Read an AMC motion for skeleton `asf` (from read_asf) into a Motion at
    `rate_hz` (AMC files do not record a rate; CMU captures at 120 Hz)."""
    path = Path(path)
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"frame rate must be positive and finite, got {rate_hz}")
    data = read_file_bytes(path)
    if b"\x00" in data:
        raise FormatError(
            path, "binary data (NUL byte) in a text file", line=data[: data.index(b"\x00")].count(b"\n") + 1
        )
    _check_utf8_outside_comments(path, data)
    start, first_line, degrees = _amc_header(path, data)
    counts = _amc_layout(asf)
    parsed = _parse_amc_fast(path, data, start, first_line, counts)
    if parsed is None:
        parsed = _parse_amc_general(path, data, start, first_line, counts)
    _, values = parsed
    frames = values["root"].shape[0] if "root" in values else 0
    if frames == 0:
        raise InputError(f"{path}: motion has zero frames")
    for name, v in values.items():
        bad = ~np.isfinite(v)
        if bad.any():
            f = int(np.nonzero(bad.any(axis=1))[0][0])
            raise InputError(f"{path}: frame {f} (bone {name}) has a NaN or infinite value")
    if degrees is None:
        degrees = asf.angle_in_degrees
    motion = amc_to_motion(asf, values, frames, np.pi / 180.0 if degrees else 1.0, rate_hz)
    motion.name = path.stem
    motion.source = str(path)
    return motion


def amc_to_motion(
    asf: AsfSkeleton, values: dict[str, np.ndarray], frames: int, to_rad: float, rate_hz: float
) -> Motion:
    """Build local rotations/translations from per-bone AMC values ({name: (F, k)}
    in dof order, angles × to_rad = radians, lengths in file units)."""
    unit = asf.metres_per_unit
    order = joint_order(asf)
    index = {name: j for j, (name, _, _) in enumerate(order)}
    J = len(order)
    parents = np.full(J, -1, dtype=np.int64)
    offsets = np.zeros((J, 3))
    channels: list[tuple[str, ...]] = []
    end_site = np.zeros(J, dtype=bool)
    # Local rotation = pre · M · post with M about fixed axes in dof order. Fixed
    # axes applied first-listed-first equal intrinsic axes in reverse order, so all
    # M are composed in one compiled pass (bvh._channels_to_pose) from reversed columns.
    pre = quat.identity((J,))
    post = quat.identity((J,))
    rot_cols: list[np.ndarray] = []
    rot_joint: list[int] = []
    rot_code: list[int] = []
    extra = np.zeros((frames, J, 3))  # per-frame translation on top of the offset (m)
    moving = np.zeros(J, dtype=bool)  # joints whose translation varies over frames

    parent_bone = {c: p for p, kids in asf.children.items() for c in kids}

    def split(dof: tuple[str, ...], v: np.ndarray):
        """Rotation angles (F, k) + their axes, translation (F, 3), length change (F,)."""
        rot_axes = "".join(d[1].upper() for d in dof if d[0] == "r")
        angles = (
            np.stack([v[:, i] for i, d in enumerate(dof) if d[0] == "r"], axis=1) if rot_axes else np.zeros((frames, 0))
        )
        t = np.zeros((frames, 3))
        dl = np.zeros(frames)
        for i, d in enumerate(dof):
            if d[0] == "t":
                t[:, "xyz".index(d[1])] = v[:, i]
            elif d == "l":
                dl = v[:, i]
        return angles * to_rad, rot_axes, t, dl

    def add_rotations(j: int, angles: np.ndarray, axes: str):
        for k in range(len(axes) - 1, -1, -1):
            rot_cols.append(np.degrees(angles[:, k]))
            rot_joint.append(j)
            rot_code.append(3 + "XYZ".index(axes[k]))

    for j, (name, bone, kind) in enumerate(order):
        if kind == "root":
            offsets[j] = asf.root_position * unit
            angles, axes, t, _ = split(asf.root_order, values.get("root", np.zeros((frames, len(asf.root_order)))))
            pre[j] = fixed_axes_quat(asf.root_orientation, asf.root_axis)
            add_rotations(j, angles, axes)
            extra[:, j] = t * unit
            channels.append(_POS_CHANNELS + _ROT_CHANNELS)
            moving[j] = True
            continue
        b = asf.bones[bone]
        parents[j] = index[parent_bone[bone]] if kind == "bone" else index[bone]
        if kind == "end":
            offsets[j] = b.direction * b.length * unit
            end_site[j] = True
            if "l" in b.dof:
                extra[:, j] = b.direction * values[bone][:, b.dof.index("l"), None] * unit
                moving[j] = True
            channels.append(_POS_CHANNELS if moving[j] else ())
            continue
        p = parent_bone[bone]
        if p != "root":
            pb = asf.bones[p]
            offsets[j] = pb.direction * pb.length * unit
            if "l" in pb.dof:  # the parent bone stretches: this joint slides along it
                extra[:, j] += pb.direction * values[p][:, pb.dof.index("l"), None] * unit
                moving[j] = True
        if b.dof:
            angles, axes, t, _ = split(b.dof, values[bone])
            c = fixed_axes_quat(b.axis, b.axis_order)
            if axes:
                pre[j], post[j] = c, quat.conjugate(c)
                add_rotations(j, angles, axes)
            if np.any([d[0] == "t" for d in b.dof]):
                # Translation dofs are expressed in the bone's axis frame.
                extra[:, j] += quat.rotate(np.broadcast_to(c, (frames, 4)), t * unit)
                moving[j] = True
        has_rot = any(d[0] == "r" for d in b.dof)
        channels.append((_POS_CHANNELS if moving[j] else ()) + (_ROT_CHANNELS if has_rot else ()))

    rot = quat.identity((frames, J))
    if rot_cols:
        _channels_to_pose(
            np.stack(rot_cols, axis=1),
            np.array(rot_joint, dtype=np.int64),
            np.array(rot_code, dtype=np.int64),
            rot,
            np.zeros((0, 0, 3)),
            1.0,
        )
    rot = quat.mul(quat.mul(pre[None], rot), post[None])
    trans = offsets[None] + extra
    if not moving[0]:
        trans[:, 0] = offsets[0]
    skeleton = Skeleton(
        names=tuple(n for n, _, _ in order),
        parents=parents,
        offsets=offsets,
        channels=tuple(channels),
        end_site=end_site,
    )
    return Motion(skeleton, rot, trans, float(rate_hz))


def find_asf(amc_path) -> Path:
    """The ASF beside an AMC: the only .asf in the folder, else the one whose stem
    is the longest prefix of the AMC's stem (CMU: 01/01.asf for 01/01_01.amc)."""
    amc_path = Path(amc_path)
    folder = amc_path.parent
    candidates = sorted(p for p in folder.glob("*") if p.suffix.lower() == ".asf" and p.is_file())
    if len(candidates) == 1:
        return candidates[0]
    matches = [p for p in candidates if amc_path.stem.startswith(p.stem)]
    if not matches:
        raise FormatError(
            amc_path,
            f"no ASF skeleton found beside it ({len(candidates)} .asf files in {folder}, none named "
            "like a prefix of the AMC); pass the .asf path",
        )
    return max(matches, key=lambda p: len(p.stem))


def read_asf_amc(amc_path, asf_path=None, rate_hz: float = CMU_RATE_HZ) -> Motion:
    """Read an AMC motion with its ASF skeleton (found beside it when not given)."""
    amc_path = require_file(amc_path)
    asf = read_asf(find_asf(amc_path) if asf_path is None else asf_path)
    return read_amc(amc_path, asf, rate_hz=rate_hz)
