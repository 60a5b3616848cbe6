"""A motion written as a file, its format chosen by the file's suffix: `.bvh`
(`motion.bvh`, in `scale` units a metre) or `.glb` / `.gltf` (`motion.gltf`, a skinned
skeleton with its animation, always in metres). The one entry for every command and
service that writes a reconstruction: `synthesize`, a batch's items, the client; and
what reads one back (`read_motion_output`: `graphsvc report`)."""

from __future__ import annotations

from pathlib import Path

from graphsvc.errors import InputError
from graphsvc.fileio import atomic_writer
from graphsvc.motion.skeleton import Motion

BVH_SUFFIXES = (".bvh",)
GLTF_SUFFIXES = (".glb", ".gltf")
MOTION_OUTPUT_SUFFIXES = BVH_SUFFIXES + GLTF_SUFFIXES  # what a reconstruction is written as


def output_format(path) -> str:
    """'bvh', 'glb' or 'gltf' by the path's suffix; InputError for any other."""
    suffix = Path(path).suffix.lower()
    if suffix not in MOTION_OUTPUT_SUFFIXES:
        raise InputError(
            f"{path}: a motion is written as {', '.join(MOTION_OUTPUT_SUFFIXES)}, "
            f"not {suffix or 'a file without a suffix'}"
        )
    return suffix[1:]


def motion_file_bytes(path, motion: Motion, scale: float = 100.0) -> bytes:
    """The bytes `write_motion` writes to `path` (scale: a BVH's units a metre; glTF is
    in metres). InputError for a motion the format cannot hold."""
    fmt = output_format(path)
    if fmt == "bvh":
        from graphsvc.motion.bvh import bvh_document

        return bvh_document(motion, scale).encode("utf-8")
    from graphsvc.motion.gltf import gltf_bytes

    return gltf_bytes(motion, binary=fmt == "glb")


def read_motion_output(path) -> Motion:
    """A written motion read back: .glb and .gltf by `motion.gltf_read.read_gltf`, any
    other by `motion.library.load_motion` (BVH, ASF/AMC)."""
    if Path(path).suffix.lower() in GLTF_SUFFIXES:
        from graphsvc.motion.gltf_read import read_gltf

        return read_gltf(path)
    from graphsvc.motion.library import load_motion

    return load_motion(path)


def write_motion(path, motion: Motion, scale: float = 100.0) -> None:
    """Write `motion` to `path` atomically, as its suffix says (`motion_file_bytes`)."""
    data = motion_file_bytes(path, motion, scale)
    with atomic_writer(path) as f:
        f.write(data)
