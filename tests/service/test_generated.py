"""The committed gRPC stubs are exactly what grpc_tools.protoc makes of the proto."""

from __future__ import annotations

import importlib.util
import sys

import pytest

from tests.service.conftest import ROOT


def _gen_proto():
    spec = importlib.util.spec_from_file_location("gen_proto", ROOT / "tools" / "gen_proto.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_committed_stubs_match_the_proto():
    pytest.importorskip("grpc_tools", reason="grpcio-tools is in the [test] extra")
    gen = _gen_proto()
    generated = gen.generate()
    assert set(generated) == {"graphsvc_pb2.py", "graphsvc_pb2.pyi", "graphsvc_pb2_grpc.py"}
    stale = gen.stale_files(generated)
    if stale:
        import grpc_tools

        version = getattr(grpc_tools, "__version__", None) or _dist_version("grpcio-tools")
        pytest.fail(
            f"stale stubs {stale} in {gen.OUT_DIR}: regenerate with `{sys.executable} tools/gen_proto.py` "
            f"(grpcio-tools {version}; the [test] extra pins the version the stubs were made with)"
        )


def _dist_version(name: str) -> str:
    from importlib.metadata import version

    return version(name)


def test_descriptor_names_the_proto_package():
    from graphsvc.service._generated import graphsvc_pb2 as pb

    assert pb.DESCRIPTOR.name == "graphsvc/v1/graphsvc.proto"
    assert pb.DESCRIPTOR.package == "graphsvc.v1"
    methods = [m.name for m in pb.DESCRIPTOR.services_by_name["MotionGraphService"].methods]
    assert methods == [
        "ListGraphs",
        "GetGraph",
        "Synthesize",
        "StreamSynthesize",
        "SubmitBatch",
        "GetBatch",
        "ListBatches",
        "CancelBatch",
    ]
    # The values a client already sends keep their numbers; strategies added since follow.
    assert [(v.name, v.number) for v in pb.Strategy.DESCRIPTOR.values][:4] == [
        ("STRATEGY_UNSPECIFIED", 0),
        ("STRATEGY_VITERBI", 1),
        ("STRATEGY_OLNG", 2),
        ("STRATEGY_SSG", 3),
    ]
    assert pb.Strategy.Value("STRATEGY_NEAREST") == 4
    # A request's fields keep their numbers: calibrate_from_start (released first) is 4,
    # performer (on a branch that also took 4) follows as 5.
    assert {f.name: f.number for f in pb.SynthesizeRequest.DESCRIPTOR.fields} == {
        "graph": 1,
        "recording": 2,
        "options": 3,
        "calibrate_from_start": 4,
        "performer": 5,
    }
