"""The seed corpus of every fuzz target, generated procedurally (never real data):
small but complete inputs each reader accepts, so mutations start inside its format.
Deterministic: the same seeds every run. `seed_corpus(name)` → list of bytes."""

from __future__ import annotations

import atexit
import functools
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

ASF = """\
# a small acclaim skeleton
:version 1.10
:name fuzz
:units
  mass 1.0
  length 0.45
  angle deg
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name lhip
     direction 1 -1 0
     length 2
     axis 0 0 45 XYZ
  end
  begin
     id 2
     name lleg
     direction 0 -1 0
     length 8
     axis 10 20 30 ZYX
     dof rz rx
     limits (-160.0 20.0)
            (-70.0 70.0)
  end
  begin
     id 3
     name spine
     direction 0.1 1 0
     length 5
     axis -90 0 20 YXZ
     dof ry rx rz
  end
:hierarchy
  begin
    root lhip spine
    lhip lleg
  end
"""

AMC = """\
#!OML:ASF fuzz.asf
:FULLY-SPECIFIED
:DEGREES
1
root 1 2 3 30 10 20
lleg 15 -40
spine 5 6 7
2
root 1.5 2 3.5 -10 0 -20
lleg 0 90
spine -5 0 3
3
root 2 2 4 0 5 5
lleg 30 30
spine 1 2 3
"""


def _scratch() -> Path:
    path = Path(tempfile.mkdtemp(prefix="graphsvc-seeds-"))
    atexit.register(shutil.rmtree, path, True)
    return path


def small_motion(frames: int = 6, end_site: bool = True):
    """A 4-joint chain with a root translation, moving a little each frame."""
    from graphsvc.motion import quat
    from graphsvc.motion.skeleton import Motion, Skeleton

    names = ("Hips", "Spine", "Head", "Head_End") if end_site else ("Hips", "Spine", "Head", "Arm")
    channels = (
        ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"),
        ("Zrotation", "Xrotation", "Yrotation"),
        ("Xrotation",),
        () if end_site else ("Yrotation",),
    )
    sk = Skeleton(
        names,
        np.array([-1, 0, 1, 2]),
        np.array([[0, 0.9, 0], [0, 0.2, 0], [0, 0.3, 0], [0, 0.1, 0]]),
        channels,
        np.array([False, False, False, end_site]),
    )
    k = np.arange(frames, dtype=np.float64)[:, None]
    angles = np.concatenate([0.1 * k, 0.05 * k, -0.02 * k], axis=1)
    rot = np.repeat(quat.from_euler(angles, "ZXY")[:, None], 4, axis=1)
    trans = np.broadcast_to(sk.offsets, (frames, 4, 3)).copy()
    trans[:, 0, 0] = 0.01 * k[:, 0]
    return Motion(sk, rot, trans, 30.0, name="seed")


def bvh_seeds() -> list[bytes]:
    from graphsvc.motion.bvh import bvh_text

    return [bvh_text(small_motion()).encode(), bvh_text(small_motion(3, end_site=False), scale=1000.0).encode()]


def deepmimic_seeds() -> list[bytes]:
    """A DeepMimic humanoid file of three frames at uneven durations, every joint
    turned a little, written as pybullet's files are (JSON, "Loop" first)."""
    from graphsvc.motion import quat
    from graphsvc.motion.deepmimic import WIDTH, humanoid_character

    character = humanoid_character()
    frames = []
    for k, duration in enumerate((1 / 30, 1 / 60, 0.0)):
        row = [duration, 0.1 * k, 0.85, 0.05 * k] + quat.about_y(0.2 * k).tolist()
        for j, kind in enumerate(character.kinds[1:]):
            if kind == "spherical":
                row += quat.from_euler(np.array([0.1 * k, 0.02 * j, -0.03 * k]), "ZXY").tolist()
            row += [-0.3 * k] * (WIDTH[kind] if kind == "revolute" else 0)
        frames.append(row)
    return [json.dumps({"Loop": "wrap", "Frames": frames}, indent=1).encode()]


def gltf_seeds() -> list[bytes]:
    """A binary glTF and a JSON one with its buffer embedded, as graphsvc writes them."""
    from graphsvc.motion.gltf import gltf_bytes

    return [gltf_bytes(small_motion()), gltf_bytes(small_motion(3, end_site=False), binary=False)]


def sensor_recording(samples: int = 8, markers: bool = False, orientations: bool = True):
    """A kelly6 recording: accelerations with a missing reading, orientations, ground
    position, heading, a constraint set and the layout; or (markers) two markers."""
    from graphsvc.sensors.layout import PRESETS
    from graphsvc.sensors.recording import Recording

    rng = np.random.default_rng(0)
    t = np.arange(samples) / 30.0
    if markers:
        pos = rng.normal(0.0, 0.3, (samples, 2, 3)) + np.array([0.0, 1.0, 0.0])
        pos[2, 1] = np.nan
        return Recording(
            rate_hz=30.0,
            timestamps_s=t,
            sensor_names=(),
            accelerations=None,
            marker_names=("LWRA", "RTOE"),
            marker_positions=pos,
            meta={"source": "seed"},
        )
    layout = PRESETS["kelly6"]
    names = layout.sensor_names
    acc = rng.normal(0.0, 3.0, (samples, len(names), 3)).astype(np.float32)
    acc[1, 2] = np.nan
    q = None
    if orientations:
        q = rng.normal(size=(samples, len(names), 4))
        q = (q / np.linalg.norm(q, axis=-1, keepdims=True)).astype(np.float32)
    return Recording(
        rate_hz=30.0,
        timestamps_s=t,
        sensor_names=names,
        accelerations=acc,
        ground_position=rng.normal(size=(samples, 2)),
        heading=rng.normal(size=samples),
        constraints=[[{"start_s": 0.0, "end_s": 0.1, "require": {"contact": "left"}}]],
        layout=layout.to_dict(),
        meta={"source": "seed"},
        orientations=q,
    )


def rec_seeds() -> list[bytes]:
    from graphsvc.sensors.recording import save_recording

    out = []
    folder = _scratch()
    for k, rec in enumerate((sensor_recording(), sensor_recording(markers=True))):
        save_recording(rec, folder / f"{k}.rec")
        out.append((folder / f"{k}.rec").read_bytes())
    return out


def csv_seeds() -> list[bytes]:
    from graphsvc.sensors.recording import export_csv

    folder = _scratch()
    export_csv(sensor_recording(orientations=False), folder / "a.csv")
    device = (
        "# units=g\n# up=z\n# sensor_frame=device\nt_s,wrist_ax,wrist_ay,wrist_az,wrist_qw,wrist_qx,wrist_qy,"
        "wrist_qz\n0,0.1,-1,0,1,0,0,0\n0.01,0.2,-0.9,nan,0.7071,0.7071,0,0\n0.02,,,,,,,\n"
    )
    return [(folder / "a.csv").read_bytes(), device.encode()]


def marker_csv_seeds() -> list[bytes]:
    from graphsvc.sensors.optical import export_marker_csv

    folder = _scratch()
    export_marker_csv(sensor_recording(markers=True), folder / "m.csv")
    mm = "# units=mm\n# up=z\ntime,A_x,A_y,A_z,B_x,B_y,B_z\n0,1,2,1000,3,4,900\n0.01,1,2,,3,4,901\n0.02,2,2,1001,,,\n"
    return [(folder / "m.csv").read_bytes(), mm.encode()]


def c3d_seeds() -> list[bytes]:
    """Two C3D files written by ezc3d: float points with a gap, and two labelled markers."""
    import ezc3d

    folder = _scratch()
    out = []
    for k, (labels, frames) in enumerate(((("LFHD", "RTOE", "*3"), 5), (("A",), 2))):
        c = ezc3d.c3d()
        c["parameters"]["POINT"]["RATE"]["value"] = [100.0]
        c["parameters"]["POINT"]["LABELS"]["value"] = list(labels)
        c["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
        pts = np.ones((4, len(labels), frames))
        pts[:3] = np.arange(3 * len(labels) * frames, dtype=np.float64).reshape(3, len(labels), frames) * 10.0
        pts[2] += 900.0
        c["data"]["points"] = pts
        if frames > 2:
            c["data"]["meta_points"]["residuals"] = np.zeros((1, len(labels), frames))
            c["data"]["meta_points"]["residuals"][0, 0, 1] = -1.0
        path = folder / f"{k}.c3d"
        c.write(str(path))
        out.append(path.read_bytes())
    return out


def mvnx_seeds() -> list[bytes]:
    ns = "http://www.xsens.com/mvn/mvnx"
    frames = []
    for k in range(3):
        acc = " ".join(f"{0.1 * (k + j):.3f}" for j in range(6))
        q = "1 0 0 0 0.7071 0 0.7071 0"
        frames.append(
            f'      <frame time="{k * 17}" index="{k}" type="normal">\n'
            f"        <sensorFreeAcceleration>{acc}</sensorFreeAcceleration>\n"
            f"        <sensorOrientation>{q}</sensorOrientation>\n      </frame>"
        )
    text = "\n".join(
        [
            '<?xml version="1.0" encoding="UTF-8"?>',
            f'<mvnx xmlns="{ns}" version="3">',
            '  <subject label="s" frameRate="60" segmentCount="23">',
            "    <sensors>",
            '      <sensor label="Pelvis"/>',
            '      <sensor label="LeftForeArm"/>',
            "    </sensors>",
            '    <frames segmentCount="23" sensorCount="2" jointCount="22">',
            '      <frame time="0" index="" type="identity"/>',
            *frames,
            "    </frames>",
            "  </subject>",
            "</mvnx>",
            "",
        ]
    )
    return [text.encode()]


@functools.cache
def graph_bytes() -> bytes:
    """A small graph file built from half a minute of the procedural knowledge base."""
    from graphsvc.graph.build import BuildOptions, build_graph
    from graphsvc.graph.file import save_graph
    from graphsvc.motion.procedural import generate_knowledge_base
    from graphsvc.sensors.layout import PRESETS

    kb = generate_knowledge_base(seed=0, minutes=0.1)
    graph, _ = build_graph(kb, BuildOptions(layout=PRESETS["wrists-ankles"], progress=False))
    path = _scratch() / "seed.graph"
    save_graph(graph, path)
    return path.read_bytes()


def graph_seeds() -> list[bytes]:
    return [graph_bytes()]


def layout_seeds() -> list[bytes]:
    from graphsvc.sensors.layout import PRESETS

    doc = PRESETS["kelly6"].to_dict()
    doc["sensors"][0]["offset_m"] = [0.01, 0.0, -0.02]
    doc["sensors"][1]["rotation_wxyz"] = [0.7071, 0.7071, 0, 0]
    return [json.dumps(doc, indent=1).encode(), json.dumps(PRESETS["wrists-ankles"].to_dict()).encode()]


def layout_toml_seeds() -> list[bytes]:
    return [
        b'name = "two"\n[[sensors]]\nname = "a"\nsegment = "l_elbow"\nalong = 0.9\n'
        b'[[sensors]]\nsegment = "pelvis"\ntoward = "spine"\noffset_m = [0.0, 0.1, 0.0]\n'
    ]


def constraints_seeds() -> list[bytes]:
    sets = [
        [
            {"start_s": 0.0, "end_s": 1.5, "require": {"label": "walk"}},
            {"start_s": 2.0, "end_s": 2.5, "require": {"contact": "both"}},
        ],
        [{"start_s": 0.5, "end_s": 1.0, "require": {"contact": "none"}}],
    ]
    return [json.dumps(sets, indent=1).encode(), b"[]"]


def calibration_seeds() -> list[bytes]:
    from graphsvc.sensors.calibration import FORMAT, VERSION

    doc = {
        "format": FORMAT,
        "version": VERSION,
        "sensor_frames": "anatomical",
        "pose": "npose",
        "sensors": {
            "l_forearm": {"rotation_wxyz": [1, 0, 0, 0]},
            "r_shin": {"rotation_wxyz": [0.7071068, 0, 0.7071068, 0]},
        },
    }
    return [json.dumps(doc, indent=1, sort_keys=True).encode()]


def performer_seeds() -> list[bytes]:
    from graphsvc.motion.proportions import FORMAT, VERSION

    doc = {
        "format": FORMAT,
        "version": VERSION,
        "name": "actor",
        "height_m": 1.8,
        "segments_m": {"l_thigh": 0.46, "r_thigh": 0.46, "neck": 0.11, "l_foot": 0.15},
    }
    return [json.dumps(doc, indent=1, sort_keys=True).encode()]


def manifest_seeds() -> list[bytes]:
    text = (
        "# a match\nrecording,graph,strategy,output,weights,options\n"
        'a.rec,g.graph,viterbi,p1,"0.5,1,1","{""beam"": 10, ""latency"": 2}"\n'
        'b.csv,g.graph,olng,p2,,"{""olng-k"": 64}"\n'
    )
    return [text.encode()]


def manifest_json_seeds() -> list[bytes]:
    items = {
        "items": [
            {
                "recording": "a.rec",
                "graph": "g",
                "strategy": "viterbi",
                "output": "p1",
                "weights": [0.5, 1, 1],
                "options": {"beam": 10, "track-pull": 0.2},
            },
            {
                "recording": "b.c3d",
                "graph": "g",
                "strategy": "ssg",
                "output": "p2",
                "options": {"markers": "hands-feet", "keep": ["LWRA", "RWRA"]},
            },
        ]
    }
    return [json.dumps(items, indent=1).encode()]


def mapping_seeds() -> list[bytes]:
    return [json.dumps({"pelvis": "Hips", "head": "Head", "l_wrist": "LeftHand"}).encode()]


def marker_set_seeds() -> list[bytes]:
    doc = {
        "name": "mine",
        "markers": [
            {"name": "LWRA", "segment": "l_elbow", "toward": "l_wrist", "along": 1.0},
            {"name": "HEAD", "segment": "head", "offset_m": [0, 0.1, 0.05]},
        ],
    }
    return [json.dumps(doc).encode()]


def device_map_seeds() -> list[bytes]:
    return [
        json.dumps({"device": "xsens", "sensors": {"LeftForeArm": "l_forearm", "Pelvis": "lower_back"}}).encode(),
        json.dumps({"a": "l_wrist"}).encode(),
    ]


def grpc_synthesize_seeds() -> list[bytes]:
    from graphsvc.service._generated import graphsvc_pb2 as pb
    from graphsvc.service.convert_recording import recording_to_proto
    from graphsvc.service.options_proto import options_to_proto
    from graphsvc.strategies.options import Options
    from graphsvc.strategies.ssg.options import SsgOptions

    rec = sensor_recording(5)
    a = pb.SynthesizeRequest(
        graph="g",
        recording=recording_to_proto(rec),
        options=options_to_proto(Options(beam=10.0, latency_s=1.0), constraints=rec.constraints),
    )
    m = pb.SynthesizeRequest(
        graph="g",
        recording=recording_to_proto(sensor_recording(4, markers=True)),
        options=options_to_proto(Options(strategy="ssg", ssg=SsgOptions(markers="hands-feet", keep=("LWRA",)))),
    )
    h = pb.SynthesizeRequest(graph="g", recording=recording_to_proto(rec), performer=pb.Performer(height_m=1.8))
    p = pb.SynthesizeRequest(
        graph="g",
        recording=recording_to_proto(rec),
        performer=pb.Performer(segments=pb.PerformerSegments(segments_m={"l_thigh": 0.46, "neck": 0.11})),
    )
    return [r.SerializeToString(deterministic=True) for r in (a, m, h, p)]


def grpc_stream_seeds() -> list[bytes]:
    from graphsvc.service._generated import graphsvc_pb2 as pb
    from graphsvc.service.convert_recording import sample_to_proto
    from graphsvc.service.options_proto import options_to_proto
    from graphsvc.strategies.olng.options import OlngOptions
    from graphsvc.strategies.options import Options

    rec = sensor_recording(2)
    config = pb.StreamSynthesizeRequest(
        config=pb.StreamConfig(
            graph="g",
            options=options_to_proto(Options(strategy="olng", olng=OlngOptions(k=32))),
            sensor_names=list(reversed(rec.sensor_names)),
            marker_names=["LWRA", "RTOE"],
            orientations=True,
        )
    )
    sample = sample_to_proto(
        0.5,
        rec.accelerations[0],
        rec.ground_position[0],
        rec.heading[0],
        markers=np.zeros((2, 3)),
        orientations=rec.orientations[0],
    )
    return [
        config.SerializeToString(deterministic=True),
        pb.StreamSynthesizeRequest(sample=sample).SerializeToString(deterministic=True),
    ]
