"""The fuzz targets: one per reader, each a function taking the input's bytes, with
the exceptions it may raise (the project's input errors, `graphsvc.errors`) and its
seed corpus (`graphsvc.fuzz.seeds`). Anything else it raises, a hang or an
allocation beyond the bound is a finding (`graphsvc.fuzz.run`).

File readers see the bytes as a file with the format's suffix in a scratch folder
(their real entry point, path in); `rec-sealed` and `graph-sealed` first give the bytes
a valid trailer (length and SHA-256), so mutations reach the header's and arrays'
checks behind the checksum; the gRPC targets decode a serialized request as the
server does before it runs anything. Each target imports its reader inside itself, so
a fuzzing child loads only the one it runs."""

from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from graphsvc.errors import GraphsvcError
from graphsvc.fuzz import seeds


@dataclass(frozen=True)
class Target:
    """name: the table's key; run: bytes → None or a text saying what it did with
    the input (an outcome's signature: `run`), raising only `allowed` on bad input;
    seeds: () → the seed corpus; structured: a format-aware mutator (bytes, random.Random
    → bytes) used beside the byte-level ones, or None."""

    name: str
    run: Callable[[bytes], object]
    seeds: Callable[[], list[bytes]]
    allowed: tuple[type[BaseException], ...] = (GraphsvcError,)
    structured: Callable | None = None
    doc: str = ""
    in_process: bool = True  # False: a finding may end the process (tools/fuzz.py's supervised child only)


_SCRATCH: Path | None = None


def scratch() -> Path:
    """A private folder for this process's input files (one per process, reused)."""
    global _SCRATCH
    if _SCRATCH is None or not _SCRATCH.is_dir():
        _SCRATCH = Path(tempfile.mkdtemp(prefix=f"graphsvc-fuzz-{os.getpid()}-"))
        atexit.register(shutil.rmtree, _SCRATCH, True)
    return _SCRATCH


def as_file(data: bytes, name: str) -> Path:
    path = scratch() / name
    path.write_bytes(data)
    return path


# ---------------------------------------------------------------- file readers


def _bvh(data: bytes) -> None:
    from graphsvc.motion.bvh import read_bvh

    read_bvh(as_file(data, "in.bvh"))


def _deepmimic(data: bytes) -> None:
    from graphsvc.motion.deepmimic import read_deepmimic

    read_deepmimic(as_file(data, "in.txt"))


def _gltf(data: bytes) -> None:
    from graphsvc.motion.gltf_read import read_gltf

    read_gltf(as_file(data, "in.glb"))


def _asf(data: bytes) -> None:
    from graphsvc.motion.asfamc import read_asf_amc

    read_asf_amc(as_file(seeds.AMC.encode(), "in.amc"), as_file(data, "in.asf"))


def _amc(data: bytes) -> None:
    from graphsvc.motion.asfamc import read_asf_amc

    read_asf_amc(as_file(data, "in.amc"), as_file(seeds.ASF.encode(), "in.asf"))


def _reader(suffix: str) -> Callable[[bytes], None]:
    def run(data: bytes) -> None:
        from graphsvc.sensors.files import read_recording

        read_recording(as_file(data, "in" + suffix))

    return run


def _c3d_ezc3d(data: bytes) -> None:
    """The structure check, then ezc3d in this process: what the child process of
    `read_c3d` is there to absorb (a crash here ends the process)."""
    import ezc3d

    from graphsvc.sensors.c3d_guard import check_c3d

    path = as_file(data, "in.c3d")
    check_c3d(path, data)
    try:
        ezc3d.c3d(str(path))
    except (RuntimeError, OSError, ValueError, IndexError, KeyError, TypeError):
        pass  # ezc3d refusing the file is what read_c3d turns into a FormatError


def reseal(data: bytes) -> bytes:
    """`data` with its last 48 bytes replaced by a container trailer that matches it
    (total length and SHA-256 of what precedes): a file damaged, or forged, and then
    checksummed again."""
    from graphsvc.store import _TRAILER, END_MAGIC

    body = data[: -_TRAILER.size] if len(data) >= _TRAILER.size else data
    return body + _TRAILER.pack(END_MAGIC, len(body) + _TRAILER.size, hashlib.sha256(body).digest())


def _rec(data: bytes) -> None:
    from graphsvc.sensors.recording import load_recording

    load_recording(as_file(data, "in.rec"))


def _graph(data: bytes) -> None:
    from graphsvc.graph.file import load_graph

    load_graph(as_file(data, "in.graph"), mmap=False)


def _layout(suffix: str) -> Callable[[bytes], None]:
    def run(data: bytes) -> None:
        from graphsvc.sensors.layout import load_layout

        load_layout(str(as_file(data, "in" + suffix)))

    return run


def _constraints(data: bytes) -> None:
    from graphsvc.strategies.options import load_constraints

    load_constraints(as_file(data, "in.json"))


def _calibration(data: bytes) -> None:
    from graphsvc.sensors.calibration import load_calibration

    load_calibration(as_file(data, "in.json"))


def _performer(data: bytes) -> None:
    from graphsvc.motion.procedural.body import standard_skeleton
    from graphsvc.motion.proportions import complete_lengths, load_performer_file, performer_skeleton, segment_lengths

    sk = standard_skeleton()
    lengths = complete_lengths(segment_lengths(sk), load_performer_file(as_file(data, "in.json")))
    performer_skeleton(sk, lengths)


def _manifest(suffix: str) -> Callable[[bytes], None]:
    def run(data: bytes) -> None:
        from graphsvc.batch.manifest import option_argv, parse_item_options, read_manifest

        folder = scratch()
        for item in read_manifest(as_file(data, "in" + suffix)):
            try:  # each item's flags checked as `batch` plans it (an error fails that item only)
                parse_item_options(option_argv(item, folder))
            except GraphsvcError:
                pass

    return run


def _mapping(data: bytes) -> None:
    from graphsvc.motion.joints import load_mapping_file

    load_mapping_file(as_file(data, "in.json"))


def _marker_set(data: bytes) -> None:
    from graphsvc.sensors.markers import load_marker_set

    load_marker_set(as_file(data, "in.json"))


def _device_map(data: bytes) -> None:
    from graphsvc.sensors.devices import load_device_map

    load_device_map(as_file(data, "in.json"))


# ---------------------------------------------------------------- gRPC requests

_LAYOUT = ("l_forearm", "r_forearm", "l_shin", "r_shin", "lower_back", "chest")  # kelly6's order


def _decode(cls, data: bytes):
    """The request as gRPC hands it to the servicer; None when the bytes are not one
    (gRPC refuses those itself, before any graphsvc code runs)."""
    from google.protobuf.message import DecodeError

    try:
        return cls.FromString(data)
    except DecodeError:
        return None


def _each(*calls) -> str:
    """Run every call; each may refuse its input (a GraphsvcError) independently.
    Returns what each said (the outcome's signature: new refusals grow the corpus)."""
    said = []
    for call in calls:
        try:
            call()
            said.append("ok")
        except GraphsvcError as exc:
            said.append(f"{type(exc).__name__}: {exc}")
    return " | ".join(said)


def _grpc_synthesize(data: bytes) -> None:
    from graphsvc.service._generated import graphsvc_pb2 as pb
    from graphsvc.service.convert_recording import recording_from_proto
    from graphsvc.service.options_proto import options_from_proto, performer_from_proto
    from graphsvc.strategies import get as get_strategy

    msg = _decode(pb.SynthesizeRequest, data)
    if msg is None:
        return "not a SynthesizeRequest"
    reads_acc = [True]

    def options():
        o = options_from_proto(msg.options, "options")
        reads_acc[0] = "accelerations" in get_strategy(o.strategy).uses

    def performer():
        if msg.HasField("performer"):
            from graphsvc.motion.procedural.body import standard_skeleton

            performer_from_proto(msg.performer, standard_skeleton())

    return _each(options, lambda: recording_from_proto(msg.recording, _LAYOUT, "recording", reads_acc[0]), performer)


def _grpc_stream(data: bytes) -> None:
    from graphsvc.service._generated import graphsvc_pb2 as pb
    from graphsvc.service.convert_recording import (
        marker_names_from_proto,
        sample_from_proto,
        sample_markers_from_proto,
        sample_orientations_from_proto,
        sensor_order,
    )
    from graphsvc.service.options_proto import options_from_proto

    msg = _decode(pb.StreamSynthesizeRequest, data)
    if msg is None:
        return "not a StreamSynthesizeRequest"
    if msg.WhichOneof("message") == "config":
        config = msg.config

        def stream_checks():  # what the server checks of a config before its session opens
            from graphsvc.strategies import check_options, get

            options = check_options(options_from_proto(config.options, "config.options"))
            names = marker_names_from_proto(config.marker_names, "config.marker_names")
            get(options.strategy).check_stream(options, tuple(config.sensor_names), names)

        return _each(stream_checks, lambda: sensor_order(config.sensor_names, _LAYOUT, "config.sensor_names"))
    sample = msg.sample
    order = sensor_order(list(reversed(_LAYOUT)), _LAYOUT, "config.sensor_names")
    return _each(
        lambda: sample_from_proto(sample, len(_LAYOUT), order, 0.0, "sample[1]", True),
        lambda: sample_from_proto(sample, 4, None, None, "sample[0]", False),
        lambda: sample_markers_from_proto(sample, 2, "sample[0]"),
        lambda: sample_markers_from_proto(sample, 0, "sample[0]"),
        lambda: sample_orientations_from_proto(sample, len(_LAYOUT), order, True, "sample[0]"),
        lambda: sample_orientations_from_proto(sample, len(_LAYOUT), None, False, "sample[0]"),
    )


def _proto_mutator(message_name: str) -> Callable:
    def mutate(data: bytes, rng) -> bytes:
        from graphsvc.fuzz.mutate import mutate_message
        from graphsvc.service._generated import graphsvc_pb2 as pb

        msg = _decode(getattr(pb, message_name), data)
        if msg is None:
            return data
        mutate_message(msg, rng)
        try:
            return msg.SerializeToString()
        except Exception:  # noqa: BLE001 (a parse that lets through what serialising refuses: keep the input)
            return data

    return mutate


# ---------------------------------------------------------------- the table


TARGETS: dict[str, Target] = {
    t.name: t
    for t in (
        Target("bvh", _bvh, seeds.bvh_seeds, doc="motion.bvh.read_bvh"),
        Target("deepmimic", _deepmimic, seeds.deepmimic_seeds, doc="motion.deepmimic.read_deepmimic"),
        Target("gltf", _gltf, seeds.gltf_seeds, doc="motion.gltf_read.read_gltf (.glb and .gltf)"),
        Target("asf", _asf, lambda: [seeds.ASF.encode()], doc="motion.asfamc.read_asf_amc, the .asf"),
        Target("amc", _amc, lambda: [seeds.AMC.encode()], doc="motion.asfamc.read_asf_amc, the .amc"),
        Target("c3d", _reader(".c3d"), seeds.c3d_seeds, doc="sensors.optical.read_c3d (ezc3d)"),
        Target(
            "c3d-ezc3d",
            _c3d_ezc3d,
            seeds.c3d_seeds,
            in_process=False,
            doc="c3d_guard.check_c3d, then ezc3d in this process (what read_c3d's child absorbs)",
        ),
        Target("csv", _reader(".csv"), seeds.csv_seeds, doc="sensors.recording.import_csv (device CSV)"),
        Target("marker-csv", _reader(".csv"), seeds.marker_csv_seeds, doc="sensors.optical.read_marker_csv"),
        Target("mvnx", _reader(".mvnx"), seeds.mvnx_seeds, doc="sensors.devices.read_mvnx"),
        Target("rec", _rec, seeds.rec_seeds, doc="sensors.recording.load_recording"),
        Target("rec-sealed", lambda d: _rec(reseal(d)), seeds.rec_seeds, doc="load_recording behind a valid checksum"),
        Target("graph", _graph, seeds.graph_seeds, doc="graph.file.load_graph"),
        Target(
            "graph-sealed", lambda d: _graph(reseal(d)), seeds.graph_seeds, doc="load_graph behind a valid checksum"
        ),
        Target("layout", _layout(".json"), seeds.layout_seeds, doc="sensors.layout.load_layout (JSON)"),
        Target("layout-toml", _layout(".toml"), seeds.layout_toml_seeds, doc="sensors.layout.load_layout (TOML)"),
        Target("constraints", _constraints, seeds.constraints_seeds, doc="strategies.options.load_constraints"),
        Target("calibration", _calibration, seeds.calibration_seeds, doc="sensors.calibration.load_calibration"),
        Target(
            "performer",
            _performer,
            seeds.performer_seeds,
            doc="motion.proportions.load_performer_file, the lengths completed and a skeleton made of them",
        ),
        Target("manifest", _manifest(".csv"), seeds.manifest_seeds, doc="batch.manifest.read_manifest + item flags"),
        Target("manifest-json", _manifest(".json"), seeds.manifest_json_seeds, doc="the same, a JSON manifest"),
        Target("mapping", _mapping, seeds.mapping_seeds, doc="motion.joints.load_mapping_file"),
        Target("marker-set", _marker_set, seeds.marker_set_seeds, doc="sensors.markers.load_marker_set"),
        Target("device-map", _device_map, seeds.device_map_seeds, doc="sensors.devices.load_device_map"),
        Target(
            "grpc-synthesize",
            _grpc_synthesize,
            seeds.grpc_synthesize_seeds,
            structured=_proto_mutator("SynthesizeRequest"),
            doc="service.options_proto, convert_recording: a SynthesizeRequest's options, recording and performer",
        ),
        Target(
            "grpc-stream",
            _grpc_stream,
            seeds.grpc_stream_seeds,
            structured=_proto_mutator("StreamSynthesizeRequest"),
            doc="service.options_proto, convert_recording: a stream's config and samples",
        ),
    )
}
