"""glTF 2.0 output: a motion as a skinned skeleton with its animation, `.glb` (binary)
or `.gltf` (JSON, its buffer embedded as a base64 data URI: one self-contained file).

Layout (docs/reconstruction.md, *glTF output*): one node a joint, in the skeleton's
order (node k is joint k, end sites included, named as the skeleton names them), each
with its frame-0 local translation and rotation; one animation whose samplers hold,
per frame at the motion's rate (LINEAR, time k / rate_hz), every joint's rotation and
the root's translation (and any other joint whose translation changes); a skin over
every joint, bound in the rest pose (identity rotations, frame 0's bone offsets, the
root on the vertical axis); a mesh of one capsule a rigid bone, each skinned to the
bone's parent joint, so that viewers show a body. glTF's own conventions hold: metres,
Y up, right-handed — graphsvc's world — so no axis or unit is converted (a BVH's
`scale` does not apply).

Written by a small writer of its own, not pygltflib: the arrays are already flat numpy
arrays that go into one buffer as they are, the JSON is a handful of plain dicts, and
a GLB is a 12-byte header and two padded chunks; a wrapper library would only move
these dicts into its dataclasses and back (with four more dependencies) while the bytes
— deterministic, same motion same file — are easiest to guarantee where they are made.
The files' correctness is checked by Khronos's validator in the tests; `gltf_read`
reads them back (`graphsvc report`).
"""

from __future__ import annotations

import base64
import json
import struct

import numpy as np

from graphsvc.errors import InputError
from graphsvc.motion.skeleton import Motion

# The capsules: sides around a bone, rings a hemisphere, the radius as a share of the
# bone's length up to a limb's; bones shorter than MIN_BONE_M get none.
CAPSULE_SIDES = 10
CAPSULE_RINGS = 3
RADIUS_SHARE = 0.22
MAX_RADIUS_M = 0.045
MIN_BONE_M = 0.01

_FLOAT, _UBYTE, _USHORT, _UINT = 5126, 5121, 5123, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_TYPES = {1: "SCALAR", 3: "VEC3", 4: "VEC4", 16: "MAT4"}
_DTYPES = {_FLOAT: "<f4", _UBYTE: "u1", _USHORT: "<u2", _UINT: "<u4"}


def check_gltf_motion(motion: Motion, where: str = "the motion") -> None:
    """InputError when `motion` cannot be written as a glTF animation: no frames, or
    non-finite rotations or translations."""
    if motion.num_frames == 0:
        raise InputError(f"{where}: no frames, nothing to animate in glTF (the output needs at least one pose)")
    for label, arr in (("rotations", motion.rotations), ("translations", motion.translations)):
        bad = ~np.isfinite(arr).all(axis=(1, 2))
        if bad.any():
            raise InputError(f"{where}: non-finite {label} at frame {int(np.nonzero(bad)[0][0])}; not written as glTF")
    if (np.linalg.norm(motion.rotations, axis=-1) < 1e-9).any():
        raise InputError(f"{where}: a zero rotation quaternion; not written as glTF")


def gltf_bytes(motion: Motion, binary: bool = True) -> bytes:
    """The file `motion` is written as: GLB (binary) or glTF JSON with its buffer
    embedded. InputError (`check_gltf_motion`) for a motion glTF cannot hold."""
    check_gltf_motion(motion, motion.source or motion.name or "the motion")
    doc, blob = _document(motion)
    if not binary:
        uri = "data:application/octet-stream;base64," + base64.b64encode(blob).decode("ascii")
        doc["buffers"] = [{"byteLength": len(blob), "uri": uri}]
        return (json.dumps(doc, indent=1) + "\n").encode("utf-8")
    doc["buffers"] = [{"byteLength": len(blob)}]
    text = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    blob += b"\0" * (-len(blob) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + blob
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


class _Buffer:
    """The one buffer: arrays appended 4-byte aligned, each with its bufferView and accessor."""

    def __init__(self):
        self.parts: list[bytes] = []
        self.size = 0
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def add(self, values: np.ndarray, component: int, target: int | None = None, bounds: bool = False) -> int:
        """Append (N, C) or (N,) values as an accessor; its index. bounds: write min and max."""
        data = np.ascontiguousarray(values, dtype=_DTYPES[component])
        width = 1 if data.ndim == 1 else data.shape[1]
        pad = -self.size % 4
        self.parts.append(b"\0" * pad + data.tobytes())
        view = {"buffer": 0, "byteOffset": self.size + pad, "byteLength": data.nbytes}
        if target is not None:
            view["target"] = target
        self.views.append(view)
        self.size += pad + data.nbytes
        accessor = {
            "bufferView": len(self.views) - 1,
            "componentType": component,
            "count": int(data.shape[0]),
            "type": _TYPES[width],
        }
        if bounds:
            flat = data.reshape(data.shape[0], width)
            accessor["min"] = [_number(v) for v in flat.min(axis=0)]
            accessor["max"] = [_number(v) for v in flat.max(axis=0)]
        self.accessors.append(accessor)
        return len(self.accessors) - 1

    def blob(self) -> bytes:
        return b"".join(self.parts)


def _number(v) -> int | float:
    return int(v) if isinstance(v, np.integer) else float(v) + 0.0


def _document(motion: Motion) -> tuple[dict, bytes]:
    sk = motion.skeleton
    J, F = sk.num_joints, motion.num_frames
    buf = _Buffer()
    rot = continuous_xyzw(motion.rotations)  # (F, J, 4) glTF's x, y, z, w
    trans = motion.translations.astype(np.float32)
    moves = np.zeros(J, bool)
    moves[0] = True
    moves[1:] = (trans[:, 1:] != trans[:1, 1:]).any(axis=(0, 2))
    turns = ~sk.end_site

    nodes = []
    for j in range(J):
        node: dict = {"name": sk.names[j]}
        children = [int(c) for c in np.nonzero(sk.parents == j)[0]]
        if children:
            node["children"] = children
        node["translation"] = [_number(v) for v in trans[0, j]]
        if turns[j]:
            node["rotation"] = [_number(v) for v in rot[0, j]]
        nodes.append(node)

    bind = bind_pose(motion)
    meshes, ibm = [], None
    pos, normal, joint, index = capsule_mesh(bind, sk.parents, rigid=~moves)
    if index.size:
        inverse_bind = np.zeros((J, 4, 4), np.float32)
        inverse_bind[:, [0, 1, 2, 3], [0, 1, 2, 3]] = 1.0
        inverse_bind[:, :3, 3] = -bind
        ibm = buf.add(inverse_bind.transpose(0, 2, 1).reshape(J, 16), _FLOAT)  # column-major
        attrs = {
            "POSITION": buf.add(pos, _FLOAT, _ARRAY_BUFFER, bounds=True),
            "NORMAL": buf.add(normal, _FLOAT, _ARRAY_BUFFER),
        }
        joints4 = np.zeros((joint.size, 4), np.int64)
        joints4[:, 0] = joint
        attrs["JOINTS_0"] = buf.add(joints4, _UBYTE if J <= 256 else _USHORT, _ARRAY_BUFFER)
        weights = np.zeros((joint.size, 4), np.float32)
        weights[:, 0] = 1.0
        attrs["WEIGHTS_0"] = buf.add(weights, _FLOAT, _ARRAY_BUFFER)
        indices = buf.add(index, _USHORT if pos.shape[0] <= 65535 else _UINT, _ELEMENT_ARRAY_BUFFER)
        meshes.append({"name": "body", "primitives": [{"attributes": attrs, "indices": indices, "material": 0}]})
        nodes.append({"name": "body", "mesh": 0, "skin": 0})

    times = buf.add(np.arange(F, dtype=np.float64) / float(motion.rate_hz), _FLOAT, bounds=True)
    samplers, channels = [], []
    for j in range(J):
        for path, values, wanted in (("translation", trans[:, j], moves[j]), ("rotation", rot[:, j], turns[j])):
            if wanted:
                channels.append({"sampler": len(samplers), "target": {"node": j, "path": path}})
                samplers.append({"input": times, "interpolation": "LINEAR", "output": buf.add(values, _FLOAT)})

    doc = {
        "asset": {"version": "2.0", "generator": "graphsvc"},
        "scene": 0,
        "scenes": [
            {
                "name": motion.name or "motion",
                "nodes": [0] + ([J] if meshes else []),
                "extras": {"rate_hz": float(motion.rate_hz), "frames": F},
            }
        ],
        "nodes": nodes,
        "animations": [{"name": motion.name or "motion", "channels": channels, "samplers": samplers}],
    }
    if meshes:
        doc["skins"] = [{"name": "skeleton", "joints": list(range(J)), "skeleton": 0, "inverseBindMatrices": ibm}]
        doc["meshes"] = meshes
        doc["materials"] = [
            {
                "name": "body",
                "pbrMetallicRoughness": {
                    "baseColorFactor": [0.72, 0.74, 0.78, 1.0],
                    "metallicFactor": 0.0,
                    "roughnessFactor": 0.8,
                },
            }
        ]
    doc["accessors"] = buf.accessors
    doc["bufferViews"] = buf.views
    return doc, buf.blob()


def continuous_xyzw(rotations: np.ndarray) -> np.ndarray:
    """(F, J, 4) w, x, y, z quaternions as unit float32 x, y, z, w, each joint's sign
    chosen so that consecutive frames lie in one hemisphere (a viewer interpolating
    between frames then turns the short way)."""
    q = rotations / np.linalg.norm(rotations, axis=-1, keepdims=True)
    flip = np.ones(q.shape[:2])
    if q.shape[0] > 1:
        flip[1:] = np.cumprod(np.where((q[1:] * q[:-1]).sum(axis=-1) < 0, -1.0, 1.0), axis=0)
    q = q * flip[..., None]
    return q[..., [1, 2, 3, 0]].astype(np.float32)


def bind_pose(motion: Motion) -> np.ndarray:
    """(J, 3) the joints' world positions in the pose the skin is bound in: identity
    rotations, frame 0's local translations, the root over the origin at its height."""
    local = motion.translations[0].astype(np.float32).astype(np.float64)
    world = np.zeros_like(local)
    world[0] = (0.0, local[0, 1], 0.0)
    for j in range(1, len(local)):
        world[j] = world[motion.skeleton.parents[j]] + local[j]
    return world


def capsule_mesh(bind: np.ndarray, parents: np.ndarray, rigid: np.ndarray) -> tuple[np.ndarray, ...]:
    """One capsule a bone (parent joint → joint) of the bind pose, each vertex skinned to
    the parent: (positions (V, 3), normals (V, 3), joint (V,), triangle indices (3T,)),
    counter-clockwise seen from outside. rigid: (J,) bool, False for a joint whose
    translation is animated: its bone changes length and gets no capsule (a Bandai-Namco
    skeleton's hips, which carry the body's position under a root on the floor)."""
    S, H = CAPSULE_SIDES, CAPSULE_RINGS
    around = 2 * np.pi * np.arange(S) / S
    # rows from the start's pole to the end's: (which end, angle from the equator)
    rows = [(0, -np.pi / 2 + np.pi / 2 * k / H) for k in range(1, H + 1)] + [
        (1, np.pi / 2 * k / H) for k in range(0, H)
    ]
    positions, normals, joints, triangles = [], [], [], []
    count = 0
    for j in range(1, len(parents)):
        p = int(parents[j])
        a, b = bind[p], bind[j]
        length = float(np.linalg.norm(b - a))
        if length < MIN_BONE_M or not rigid[j]:
            continue
        u = (b - a) / length
        e1 = np.cross(u, (1.0, 0.0, 0.0) if abs(u[0]) < 0.9 else (0.0, 1.0, 0.0))
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(u, e1)
        radial = np.cos(around)[:, None] * e1 + np.sin(around)[:, None] * e2  # (S, 3)
        r = min(MAX_RADIUS_M, RADIUS_SHARE * length)
        n = [-u] + [np.cos(t) * radial + np.sin(t) * u for _, t in rows] + [u]
        c = [a] + [(a, b)[end] for end, _ in rows] + [b]
        vn = np.vstack([np.atleast_2d(x) for x in n])
        vp = np.vstack([np.atleast_2d(ci + r * ni) for ci, ni in zip(c, n)])
        last = vp.shape[0] - 1
        s = np.arange(S)
        nxt = (s + 1) % S
        tri = [np.stack([np.zeros(S, int), 1 + nxt, 1 + s], axis=1)]  # the start's cap: looks along −u
        for k in range(len(rows) - 1):
            lo, hi = 1 + k * S, 1 + (k + 1) * S
            tri.append(np.stack([lo + s, lo + nxt, hi + nxt], axis=1))
            tri.append(np.stack([lo + s, hi + nxt, hi + s], axis=1))
        top = 1 + (len(rows) - 1) * S
        tri.append(np.stack([top + s, top + nxt, np.full(S, last)], axis=1))
        positions.append(vp)
        normals.append(vn)
        joints.append(np.full(vp.shape[0], p))
        triangles.append(np.vstack(tri) + count)
        count += vp.shape[0]
    if not positions:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64)
    return (
        np.vstack(positions),
        np.vstack(normals),
        np.concatenate(joints).astype(np.int64),
        np.vstack(triangles).reshape(-1).astype(np.int64),
    )
