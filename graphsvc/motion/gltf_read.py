"""Reading a glTF 2.0 skeleton animation back as a Motion: what `graphsvc report` needs
of a reconstruction written as `.glb` or `.gltf` (`motion.gltf`), and any file of that
shape — one skin (or, without one, the scene's first node and its descendants) whose
joints list parents before children, one animation whose LINEAR or STEP samplers share
keyframes at a uniform rate, buffers in the file (GLB's binary chunk or base64 data
URIs). Each node's translation and rotation, animated or not, become the joint's local
translation and rotation per keyframe; the root and every joint whose translation is
animated get position channels, the others ZXY rotation channels; a leaf node without
a rotation sampler is an end site.

Every malformed file is a FormatError naming the file and what is wrong (fuzzed as the
`gltf` target): a broken container, JSON that is not glTF, an index out of range, an
accessor beyond its buffer, non-finite values, keyframes at no uniform rate.
"""

from __future__ import annotations

import base64
import binascii
import json
import struct
from pathlib import Path

import numpy as np

from graphsvc.errors import FormatError, GraphsvcError
from graphsvc.fileio import read_input_bytes
from graphsvc.motion.skeleton import Motion, Skeleton

_COMPONENTS = {5126: "<f4", 5121: "u1", 5123: "<u2", 5125: "<u4", 5120: "i1", 5122: "<i2"}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
JOINT_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")
RATE_TOLERANCE_S = 1e-4  # keyframe times off k / rate by more than this: not a uniform rate


def read_gltf(path) -> Motion:
    """The Motion a .glb or .gltf file animates (see the module docstring); FormatError
    for a file that is not such a glTF."""
    path = Path(path)
    data = read_input_bytes(path, "glTF file")
    try:
        doc, chunk = _container(data)
        return _motion(path, doc, chunk)
    except FormatError:
        raise
    except _Bad as exc:
        raise FormatError(path, str(exc)) from None
    except GraphsvcError as exc:
        raise FormatError(path, str(exc)) from None
    except (KeyError, IndexError, TypeError, ValueError, AttributeError, OverflowError) as exc:
        raise FormatError(path, f"not a glTF skeleton animation graphsvc reads ({type(exc).__name__}: {exc})") from None


class _Bad(ValueError):
    pass


def _container(data: bytes) -> tuple[dict, bytes | None]:
    if data[:4] == b"glTF":
        if len(data) < 20:
            raise _Bad("truncated GLB header")
        version, length = struct.unpack_from("<II", data, 4)
        if version != 2 or length != len(data):
            raise _Bad(f"GLB version {version}, length {length} for {len(data)} bytes: not a glTF 2.0 binary")
        n, kind = struct.unpack_from("<II", data, 12)
        if kind != 0x4E4F534A or 20 + n > len(data):
            raise _Bad("the GLB's first chunk is not its JSON")
        doc, chunk = _json(data[20 : 20 + n]), None
        if 28 + n <= len(data):
            m, kind = struct.unpack_from("<II", data, 20 + n)
            if kind == 0x004E4942:
                if 28 + n + m > len(data):
                    raise _Bad("the GLB's binary chunk runs past the file's end")
                chunk = data[28 + n : 28 + n + m]
        return doc, chunk
    return _json(data), None


def _json(text: bytes) -> dict:
    try:
        doc = json.loads(text.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise _Bad(f"not glTF JSON ({exc})") from None
    if (
        not isinstance(doc, dict)
        or not isinstance(doc.get("asset"), dict)
        or not str(doc["asset"].get("version", "")).startswith("2.")
    ):
        raise _Bad("not glTF 2.0 (no asset.version 2.x)")
    return doc


def _buffers(doc: dict, chunk: bytes | None) -> list[bytes]:
    out = []
    for k, b in enumerate(doc.get("buffers", [])):
        uri = b.get("uri")
        if uri is None:
            if k != 0 or chunk is None:
                raise _Bad(f"buffer {k} has no data (no uri, no GLB binary chunk)")
            data = chunk
        elif uri.startswith("data:") and ";base64," in uri:
            try:
                data = base64.b64decode(uri.split(",", 1)[1], validate=True)
            except binascii.Error:
                raise _Bad(f"buffer {k}'s data URI is not base64") from None
        else:
            raise _Bad(f"buffer {k} is an external file ({uri[:40]!r}); only embedded buffers are read")
        if len(data) < int(b["byteLength"]):
            raise _Bad(f"buffer {k} holds {len(data)} bytes, byteLength says {b['byteLength']}")
        out.append(data)
    return out


def _accessor(doc: dict, buffers: list[bytes], k: int, width: int) -> np.ndarray:
    """Accessor k as (count, width) float64; its type must be `width` wide."""
    a = doc["accessors"][_index(k)]
    if _WIDTH.get(a["type"]) != width or a["componentType"] not in _COMPONENTS:
        raise _Bad(f"accessor {k} is {a['type']} of component {a['componentType']}, expected {width} floats")
    view = doc["bufferViews"][_index(a["bufferView"])]
    dtype = np.dtype(_COMPONENTS[a["componentType"]])
    count = _index(a["count"])
    stride = int(view.get("byteStride", dtype.itemsize * width))
    start = _index(view.get("byteOffset", 0)) + _index(a.get("byteOffset", 0))
    need = (count - 1) * stride + dtype.itemsize * width if count else 0
    buf = buffers[_index(view["buffer"])]
    if (
        start + need > min(len(buf), _index(view.get("byteOffset", 0)) + _index(view["byteLength"]))
        or stride < dtype.itemsize * width
    ):
        raise _Bad(f"accessor {k} runs past its buffer view")
    rows = np.lib.stride_tricks.as_strided(
        np.frombuffer(buf, np.uint8, need, start) if need else np.zeros(0, np.uint8),
        (count, dtype.itemsize * width),
        (stride, 1),
    )
    values = np.ascontiguousarray(rows).view(dtype).reshape(count, width).astype(np.float64)
    if not np.isfinite(values).all():
        raise _Bad(f"accessor {k} holds non-finite values")
    return values


def _index(v) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise _Bad(f"{v!r} is not an index or count")
    return v


def _joints(doc: dict) -> list[int]:
    nodes = doc["nodes"]
    skins = doc.get("skins") or []
    if skins:
        joints = [_index(j) for j in skins[0]["joints"]]
    else:
        scene = doc["scenes"][_index(doc.get("scene", 0))]
        joints, stack = [], [_index(scene["nodes"][0])]
        while stack:
            k = stack.pop()
            if k in joints or len(joints) > len(nodes):
                raise _Bad("the node hierarchy has a cycle")
            joints.append(k)
            stack.extend(reversed([_index(c) for c in nodes[k].get("children", [])]))
    for k in joints:
        nodes[k]  # (an index out of range raises here)
    return joints


def _motion(path: Path, doc: dict, chunk: bytes | None) -> Motion:
    buffers = _buffers(doc, chunk)
    nodes = doc["nodes"]
    joints = _joints(doc)
    where = {k: j for j, k in enumerate(joints)}
    if len(where) != len(joints) or not joints:
        raise _Bad("the skin lists no joints, or a node twice")
    parent_of = {}
    for k, n in enumerate(nodes):
        for c in n.get("children", []):
            if _index(c) in parent_of:
                raise _Bad(f"node {c} has two parents")
            parent_of[_index(c)] = k
    parents = np.full(len(joints), -1, np.int64)
    for j, k in enumerate(joints[1:], 1):
        p = where.get(parent_of.get(k, -1), -1)
        if not 0 <= p < j:
            raise _Bad(f"joint {nodes[k].get('name', k)!r}'s parent is not a joint listed before it")
        parents[j] = p
    for k in joints:
        if "matrix" in nodes[k] or any(abs(float(s) - 1.0) > 1e-6 for s in nodes[k].get("scale", (1, 1, 1))):
            raise _Bad(
                f"node {nodes[k].get('name', k)!r} has a matrix or a scale; only translation and rotation are read"
            )

    anims = doc.get("animations") or []
    if not anims:
        raise _Bad("no animation")
    times, animated = None, {}
    for ch in anims[0]["channels"]:
        target = ch["target"]
        if target.get("node") not in where or target["path"] not in ("translation", "rotation"):
            continue
        sampler = anims[0]["samplers"][_index(ch["sampler"])]
        if sampler.get("interpolation", "LINEAR") not in ("LINEAR", "STEP"):
            raise _Bad(f"{sampler['interpolation']} samplers are not read (LINEAR or STEP)")
        t = _accessor(doc, buffers, sampler["input"], 1)[:, 0]
        if times is None:
            times = t
        elif t.shape != times.shape or np.abs(t - times).max(initial=0.0) > RATE_TOLERANCE_S:
            raise _Bad("the animation's samplers have different keyframes")
        width = 3 if target["path"] == "translation" else 4
        values = _accessor(doc, buffers, sampler["output"], width)
        if values.shape[0] != t.shape[0]:
            raise _Bad(f"a sampler has {values.shape[0]} values for {t.shape[0]} keyframes")
        animated[(where[target["node"]], target["path"])] = values
    if times is None or times.size == 0:
        raise _Bad("the animation moves none of the skeleton's joints")
    rate = _rate(doc, times)
    F, J = times.size, len(joints)
    rotations = np.empty((F, J, 4))
    translations = np.empty((F, J, 3))
    for j, k in enumerate(joints):
        n = nodes[k]
        t = animated.get((j, "translation"), np.array([n.get("translation", (0.0, 0.0, 0.0))], float))
        q = animated.get((j, "rotation"), np.array([n.get("rotation", (0.0, 0.0, 0.0, 1.0))], float))
        if t.shape[1] != 3 or q.shape[1] != 4 or not (np.isfinite(t).all() and np.isfinite(q).all()):
            raise _Bad(f"node {n.get('name', k)!r} has a malformed translation or rotation")
        norm = np.linalg.norm(q, axis=1, keepdims=True)
        if (norm < 1e-6).any():
            raise _Bad(f"node {n.get('name', k)!r} has a zero rotation quaternion")
        translations[:, j] = t
        rotations[:, j] = (q / norm)[:, [3, 0, 1, 2]]
    names = tuple(str(nodes[k].get("name") or f"node{k}") for k in joints)
    has_child = np.zeros(J, bool)
    has_child[parents[1:]] = True
    end_site = ~has_child & np.array([(j, "rotation") not in animated for j in range(J)])
    end_site[0] = False
    channels = tuple(
        ROOT_CHANNELS if j == 0 or (j, "translation") in animated else () if end_site[j] else JOINT_CHANNELS
        for j in range(J)
    )
    skeleton = Skeleton(names, parents, translations[0].copy(), channels, end_site)
    name = str(anims[0].get("name") or path.stem)
    return Motion(skeleton, rotations, translations, rate, name=name, source=str(path))


def _rate(doc: dict, times: np.ndarray) -> float:
    """The keyframes' uniform rate: from their spacing, or the scene's `extras.rate_hz`
    for a single keyframe."""
    if times.size == 1:
        extras = (doc.get("scenes") or [{}])[_index(doc.get("scene", 0))].get("extras") or {}
        rate = extras.get("rate_hz") if isinstance(extras, dict) else None
        if not isinstance(rate, (int, float)) or not np.isfinite(rate) or rate <= 0:
            raise _Bad("one keyframe and no extras.rate_hz: the frame rate is unknown")
        return float(rate)
    rate = (times.size - 1) / (times[-1] - times[0]) if times[-1] > times[0] else 0.0
    if (
        not (np.isfinite(rate) and rate > 0)
        or np.abs(times - times[0] - np.arange(times.size) / rate).max() > RATE_TOLERANCE_S
    ):
        raise _Bad("the keyframes are not at a uniform rate")
    extras = (doc.get("scenes") or [{}])[0].get("extras") or {}
    stated = extras.get("rate_hz") if isinstance(extras, dict) else None
    if isinstance(stated, (int, float)) and abs(stated - rate) < 1e-3 * rate:
        return float(stated)  # (the writer's rate, exact)
    return float(rate)
