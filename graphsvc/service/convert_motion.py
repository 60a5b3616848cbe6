"""Motions ↔ protocol buffers: a whole `Motion` (Synthesize), the `PoseFrame`s a live
stream sends and the Motion they make, and a reconstruction's `Provenance`.
"""

from __future__ import annotations

import numpy as np

from graphsvc.errors import FieldError, InputError
from graphsvc.motion.skeleton import Motion, Skeleton
from graphsvc.service._generated import graphsvc_pb2 as pb


def motion_to_proto(motion: Motion) -> pb.Motion:
    msg = pb.Motion(
        rate_hz=float(motion.rate_hz), frame_count=motion.num_frames, joint_count=motion.skeleton.num_joints
    )
    msg.rotations_wxyz.extend(np.asarray(motion.rotations, np.float32).ravel().tolist())
    msg.translations_m.extend(np.asarray(motion.translations, np.float32).ravel().tolist())
    return msg


def motion_from_proto(msg: pb.Motion, skeleton: Skeleton, name: str = "synthesized") -> Motion:
    F, J = msg.frame_count, msg.joint_count
    if J != skeleton.num_joints or len(msg.rotations_wxyz) != F * J * 4 or len(msg.translations_m) != F * J * 3:
        raise FieldError(
            "motion", f"arrays disagree with {F} frames of {J} joints on a {skeleton.num_joints}-joint skeleton"
        )
    rot = np.array(msg.rotations_wxyz, np.float32).reshape(F, J, 4)
    trans = np.array(msg.translations_m, np.float32).reshape(F, J, 3)
    return Motion(skeleton, rot, trans, msg.rate_hz, name=name, source="graphsvc service")


def frame_to_proto(frame, input_sample_index: int) -> pb.PoseFrame:
    """A pipeline.Frame → PoseFrame."""
    msg = pb.PoseFrame(
        index=int(frame.index),
        time_s=float(frame.time_s),
        node=int(frame.node),
        label=frame.label,
        input_sample_index=int(input_sample_index),
    )
    msg.rotations_wxyz.extend(np.asarray(frame.rotations, np.float32).ravel().tolist())
    msg.translations_m.extend(np.asarray(frame.translations, np.float32).ravel().tolist())
    msg.sources.extend(pb.FrameSource(clip=c, frame=f, weight=w) for c, f, w in frame.sources)
    return msg


def provenance_to_proto(prov) -> pb.Provenance:
    """A strategies.base.Provenance → Provenance."""
    msg = pb.Provenance(sources_per_frame=int(prov.clip.shape[1]))
    msg.clips.extend(np.asarray(prov.clip, np.int64).ravel().tolist())
    msg.frames.extend(np.asarray(prov.frame, np.float64).ravel().tolist())
    msg.weights.extend(np.asarray(prov.weight, np.float64).ravel().tolist())
    msg.labels.extend(str(x) for x in prov.label)
    return msg


def frames_to_motion(
    frames: list[pb.PoseFrame], skeleton: Skeleton, rate_hz: float, name: str = "synthesized"
) -> Motion:
    """PoseFrames (any order, consecutive indices) → one Motion."""
    J = skeleton.num_joints
    frames = sorted(frames, key=lambda f: f.index)
    if frames and [f.index for f in frames] != list(range(frames[0].index, frames[0].index + len(frames))):
        raise InputError("pose frames are not consecutive")
    rot = np.array([f.rotations_wxyz for f in frames], np.float32).reshape(len(frames), J, 4)
    trans = np.array([f.translations_m for f in frames], np.float32).reshape(len(frames), J, 3)
    return Motion(skeleton, rot, trans, rate_hz, name=name, source="graphsvc live stream")
