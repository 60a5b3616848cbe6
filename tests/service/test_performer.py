"""A Synthesize request on a performer's proportions (SynthesizeRequest.performer) and
`graphsvc client synthesize --performer | --height`: the library's output, bad
proportions INVALID_ARGUMENT naming the field."""

from __future__ import annotations

import json

import grpc
import numpy as np
import pytest

from graphsvc.cli import main
from graphsvc.motion.bvh import bvh_text, read_bvh
from graphsvc.motion.proportions import SEGMENTS, lengths_for_height, segment_lengths
from graphsvc.pipeline import put_on_performer, reconstruct
from graphsvc.service import client as C
from graphsvc.service import convert
from graphsvc.service._generated import graphsvc_pb2 as pb
from tests.service.conftest import rpc_error as _code
from tests.service.test_cli_service import served  # noqa: F401 (a fixture)


def _read_bvh_bytes(data: bytes):
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "out.bvh"
        path.write_bytes(data)
        return read_bvh(path)


def test_synthesize_on_a_height_is_the_library_s(conn, graph, recording):
    kb = segment_lengths(graph.skeleton)
    expected = put_on_performer(graph, reconstruct(graph, recording), lengths_for_height(kb, 1.96))
    got = C.synthesize(conn, "small", recording, performer=convert.performer_to_proto(height_m=1.96))
    assert got.bvh == bvh_text(expected.motion, scale=100.0).encode()
    np.testing.assert_array_equal(got.motion.translations, expected.motion.translations.astype(np.float32))
    assert got.report["performer"]["height_m"] == pytest.approx(1.96, abs=1e-4)
    on = segment_lengths(got.motion.skeleton)  # (the client's skeleton: the bones the translations carry)
    for name in SEGMENTS:  # 1.96 / 1.75
        assert on[name] == pytest.approx(1.12 * kb[name], abs=1e-6), name


def test_synthesize_on_segments_scales_the_others_by_their_mean_ratio(conn, graph, recording):
    kb = segment_lengths(graph.skeleton)
    given = {"l_thigh": 1.2 * kb["l_thigh"], "r_thigh": 1.1 * kb["r_thigh"]}
    got = C.synthesize(conn, "small", recording, performer=convert.performer_to_proto(segments_m=given))
    on = segment_lengths(_read_bvh_bytes(got.bvh).skeleton)
    for name in SEGMENTS:
        assert on[name] == pytest.approx(given.get(name, 1.15 * kb[name]), abs=1e-6), name


@pytest.mark.parametrize(
    "performer, field, mention",
    [
        (pb.Performer(height_m=-1.75), "performer.height_m", "height must be"),
        (pb.Performer(height_m=175.0), "performer.height_m", "at most 3"),
        (
            pb.Performer(segments=pb.PerformerSegments(segments_m={"tail": 0.3})),
            "performer.segments.segments_m",
            "unknown segments: tail",
        ),
        (
            pb.Performer(segments=pb.PerformerSegments(segments_m={"l_shin": float("nan")})),
            "performer.segments.segments_m",
            "l_shin must be",
        ),
        (pb.Performer(), "performer", "give height_m or segments"),
    ],
)
def test_bad_proportions_are_invalid_argument_naming_the_field(conn, recording, performer, field, mention):
    request = pb.SynthesizeRequest(graph="small", recording=convert.recording_to_proto(recording), performer=performer)
    code, details = _code(conn.stub.Synthesize, request, timeout=10)
    assert code == grpc.StatusCode.INVALID_ARGUMENT
    assert details.startswith(f"{field}: ") and mention in details, details


def test_client_synthesize_sends_a_performer(served, rec_file, graph, recording, tmp_path, capsys):  # noqa: F811
    _, address, token = served
    common = ["--server", address, "--token-file", str(token)]
    kb = segment_lengths(graph.skeleton)
    out = tmp_path / "tall.bvh"
    assert main(["client", "synthesize", str(rec_file), "-o", str(out), *common, "--height", "1.96"]) == 0
    capsys.readouterr()
    on = segment_lengths(read_bvh(out).skeleton)
    for name in SEGMENTS:
        assert on[name] == pytest.approx(1.12 * kb[name], abs=1e-6), name
    spec = tmp_path / "actor.json"  # read by the client: the server reads no files
    spec.write_text(json.dumps({"format": "graphsvc-performer", "version": 1, "segments_m": {"neck": 0.15}}))
    assert main(["client", "synthesize", str(rec_file), "-o", str(out), *common, "--performer", str(spec)]) == 0
    capsys.readouterr()
    assert segment_lengths(read_bvh(out).skeleton)["l_forearm"] == pytest.approx(1.5 * kb["l_forearm"], abs=1e-6)
    spec.write_text(json.dumps({"format": "graphsvc-performer", "version": 1, "segments_m": {"wing": 0.15}}))
    assert (
        main(["client", "synthesize", str(rec_file), "-o", str(tmp_path / "x.bvh"), *common, "--performer", str(spec)])
        == 2
    )
    err = capsys.readouterr().err
    assert "unknown segments: wing" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.bvh").exists()
