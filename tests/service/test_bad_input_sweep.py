"""The bad-argument sweep: every CLI command and every gRPC method tried with missing,
empty, oversize, non-finite and wrong-typed arguments. Each CLI case must answer one
line on stderr ("graphsvc: error: ...") and exit 2, never a traceback; each gRPC case
the given status with details naming the field, and the server keeps serving. The
CLI runs in-process (cli.main), the gRPC cases against the shared loopback server."""

from __future__ import annotations

import grpc
import pytest

from graphsvc.cli import main
from graphsvc.service import client as C
from graphsvc.service import convert
from graphsvc.service._generated import graphsvc_pb2 as pb
from tests.service.conftest import rpc_error
from tests.service.conftest import stream_requests as _requests

BIG = "1e309"  # overflows a float: inf
HUGE_INT = str(10**30)

# {graph} a built graph, {rec} a recording, {clip} a BVH clip, {kb} a folder of clips,
# {txt} a text file that is no format graphsvc reads, {dir} an empty folder, {out} a
# fresh output stem in a writable folder, {server} a running server's address.
SYN = ["synthesize", "{graph}", "{rec}", "-o", "{out}.bvh"]
SIM = ["simulate", "{clip}", "--layout", "kelly6", "-o", "{out}.rec"]
BUILD = ["build", "{kb}", "-o", "{out}.graph", "--quiet"]
CAL = ["calibrate", "{rec}", "--pose", "stand", "-o", "{out}.json"]
EVAL = ["evaluate", "{kb}", "--test", "*.bvh", "--quiet"]
CLIENT = ["--server", "{server}", "--timeout", "20"]
C_SYN = ["client", "synthesize", "{rec}", "-o", "{out}.bvh", *CLIENT]
C_STREAM = ["client", "stream", "{rec}", *CLIENT, "--quiet"]
BRIDGE = ["sensor-bridge", "--device", "{dir}/tty0", "--server", "{server}"]

CLI_CASES = {
    # inspect / info / mapping: paths
    "inspect nothing": ["inspect"],
    "inspect empty path": ["inspect", ""],
    "inspect missing": ["inspect", "{dir}/none.bvh"],
    "inspect text file": ["inspect", "{txt}"],
    "inspect garbage bvh": ["inspect", "{garbage}.bvh"],
    "inspect garbage rec": ["inspect", "{garbage}.rec"],
    "info nothing": ["info"],
    "info empty": ["info", ""],
    "info folder": ["info", "{dir}"],
    "info not a graph": ["info", "{rec}"],
    "mapping nothing": ["mapping"],
    "mapping empty": ["mapping", ""],
    "mapping garbage": ["mapping", "{garbage}.bvh"],
    # simulate
    "simulate no output": ["simulate", "{clip}", "--layout", "kelly6"],
    "simulate empty output": ["simulate", "{clip}", "--layout", "kelly6", "-o", ""],
    "simulate empty layout": ["simulate", "{clip}", "--layout", "", "-o", "{out}.rec"],
    "simulate seed text": [*SIM, "--seed", "abc"],
    "simulate seed negative": [*SIM, "--seed", "-1"],
    "simulate rate nan": [*SIM, "--rate", "nan"],
    "simulate rate inf": [*SIM, "--rate", BIG],
    "simulate rate zero": [*SIM, "--rate", "0"],
    "simulate rate huge": [*SIM, "--rate", "1e300"],
    "simulate position noise nan": [*SIM, "--position-noise", "nan"],
    "simulate position noise negative": [*SIM, "--position-noise", "-1"],
    "simulate noise empty": [*SIM, "--noise", ""],
    "simulate noise value nan": [*SIM, "--noise", "default,accel_sigma=nan"],
    "simulate flicker nan": ["simulate", "{clip}", "--markers", "hands-feet", "--flicker", "nan", "-o", "{out}.rec"],
    "simulate flicker 2": ["simulate", "{clip}", "--markers", "hands-feet", "--flicker", "2", "-o", "{out}.rec"],
    "simulate gap fraction inf": [
        "simulate",
        "{clip}",
        "--markers",
        "hands-feet",
        "--gap-fraction",
        BIG,
        "-o",
        "{out}.rec",
    ],
    "simulate gaps text": ["simulate", "{clip}", "--markers", "hands-feet", "--gaps", "a:b", "-o", "{out}.rec"],
    "simulate mapping garbage": [*SIM, "--mapping", "{txt}"],
    # build / relayout
    "build nothing": ["build"],
    "build no output": ["build", "{kb}"],
    "build empty kb": ["build", "", "-o", "{out}.graph"],
    "build empty folder": ["build", "{dir}", "-o", "{out}.graph"],
    "build rate nan": [*BUILD, "--rate", "nan"],
    "build rate inf": [*BUILD, "--rate", BIG],
    "build rate negative": [*BUILD, "--rate", "-30"],
    "build rate text": [*BUILD, "--rate", "fast"],
    "build rate huge": [*BUILD, "--rate", "1e300"],
    "build jobs zero": [*BUILD, "--jobs", "0"],
    "build jobs huge": [*BUILD, "--jobs", HUGE_INT],
    "build augment unknown": [*BUILD, "--augment", "sideways"],
    "build layout empty": [*BUILD, "--layout", ""],
    "relayout no layout": ["relayout", "{graph}", "-o", "{out}.graph"],
    "relayout empty layout": ["relayout", "{graph}", "--layout", "", "-o", "{out}.graph"],
    "relayout not a graph": ["relayout", "{txt}", "--layout", "kelly6", "-o", "{out}.graph"],
    "relayout empty output": ["relayout", "{graph}", "--layout", "kelly6", "-o", ""],
    # synthesize: every number non-finite, negative, oversize or text
    "synthesize nothing": ["synthesize"],
    "synthesize no output": ["synthesize", "{graph}", "{rec}"],
    "synthesize empty graph": ["synthesize", "", "{rec}", "-o", "{out}.bvh"],
    "synthesize empty recording": ["synthesize", "{graph}", "", "-o", "{out}.bvh"],
    "synthesize recording is a graph": ["synthesize", "{graph}", "{graph}", "-o", "{out}.bvh"],
    "synthesize graph is a recording": ["synthesize", "{rec}", "{rec}", "-o", "{out}.bvh"],
    "synthesize weights nan": [*SYN, "--weights", "nan,1,1"],
    "synthesize weights inf": [*SYN, "--weights", f"{BIG},1,1"],
    "synthesize weights text": [*SYN, "--weights", "a,b,c"],
    "synthesize weights empty": [*SYN, "--weights", ""],
    "synthesize weights five": [*SYN, "--weights", "1,1,1,1,1"],
    "synthesize latency nan": [*SYN, "--latency", "nan"],
    "synthesize latency inf": [*SYN, "--latency", BIG],
    "synthesize latency negative": [*SYN, "--latency", "-1"],
    "synthesize beam nan": [*SYN, "--beam", "nan"],
    "synthesize beam zero": [*SYN, "--beam", "0"],
    "synthesize beam inf": [*SYN, "--beam", BIG],
    "synthesize track pull nan": [*SYN, "--track-pull", "nan"],
    "synthesize track pull negative": [*SYN, "--track-pull", "-1"],
    "synthesize rest heading nan": [*SYN, "--rest-heading-deg", "nan"],
    "synthesize rest heading inf": [*SYN, "--rest-heading-deg", BIG],
    "synthesize speed threshold nan": [*SYN, "--heading-from-track", "--speed-threshold", "nan"],
    "synthesize speed threshold negative": [*SYN, "--heading-from-track", "--speed-threshold", "-1"],
    "synthesize scale nan": [*SYN, "--scale", "nan"],
    "synthesize scale zero": [*SYN, "--scale", "0"],
    "synthesize scale inf": [*SYN, "--scale", BIG],
    "synthesize olng k zero": [*SYN, "--strategy", "olng", "--olng-k", "0"],
    "synthesize olng k huge": [*SYN, "--strategy", "olng", "--olng-k", HUGE_INT],
    "synthesize olng k text": [*SYN, "--strategy", "olng", "--olng-k", "many"],
    "synthesize olng i zero": [*SYN, "--strategy", "olng", "--olng-i", "0"],
    "synthesize olng m negative": [*SYN, "--strategy", "olng", "--olng-m", "-1"],
    "synthesize olng weights nan": [*SYN, "--strategy", "olng", "--olng-weights", "nan,1,1,1,1"],
    "synthesize olng weights short": [*SYN, "--strategy", "olng", "--olng-weights", "1,1"],
    "synthesize ssg no markers": [*SYN, "--strategy", "ssg"],
    "synthesize ssg window nan": [*SYN, "--strategy", "ssg", "--markers", "hands-feet", "--ssg-window", "nan"],
    "synthesize ssg window zero": [*SYN, "--strategy", "ssg", "--markers", "hands-feet", "--ssg-window", "0"],
    "synthesize ssg overlap negative": [*SYN, "--strategy", "ssg", "--markers", "hands-feet", "--ssg-overlap", "-1"],
    "synthesize ssg k zero": [*SYN, "--strategy", "ssg", "--markers", "hands-feet", "--ssg-k", "0"],
    "synthesize ssg weight inf": [*SYN, "--strategy", "ssg", "--markers", "hands-feet", "--ssg-weight", BIG],
    "synthesize strategy unknown": [*SYN, "--strategy", "magic"],
    "synthesize constraints garbage": [*SYN, "--constraints", "{txt}"],
    "synthesize constraints folder": [*SYN, "--constraints", "{dir}"],
    "synthesize calibration garbage": [*SYN, "--calibration", "{txt}"],
    "synthesize report in a missing folder": [*SYN, "--report", "{dir}/no/r.json"],
    "synthesize output is a folder": ["synthesize", "{graph}", "{rec}", "-o", "{dir}"],
    # calibrate
    "calibrate no pose": ["calibrate", "{rec}", "-o", "{out}.json"],
    "calibrate from nan": [*CAL, "--from", "nan"],
    "calibrate to inf": [*CAL, "--to", BIG],
    "calibrate from after to": [*CAL, "--from", "2", "--to", "1"],
    "calibrate from text": [*CAL, "--from", "start"],
    "calibrate garbage recording": ["calibrate", "{txt}", "--pose", "stand", "-o", "{out}.json"],
    "calibrate graph garbage": [*CAL, "--graph", "{txt}"],
    # evaluate
    "evaluate no test": ["evaluate", "{kb}"],
    "evaluate empty test": ["evaluate", "{kb}", "--test", ""],
    "evaluate jobs zero": [*EVAL, "--jobs", "0"],
    "evaluate jobs text": [*EVAL, "--jobs", "two"],
    "evaluate mixed negative": [*EVAL, "--mixed", "-1"],
    "evaluate flicker nan": [*EVAL, "--markers", "hands-feet", "--strategy", "ssg", "--flicker", "nan"],
    "evaluate position noise inf": [*EVAL, "--position-noise", BIG],
    "evaluate latency nan": [*EVAL, "--latency", "nan"],
    "evaluate graph garbage": [*EVAL, "--graph", "{txt}"],
    "evaluate seed huge": [*EVAL, "--seed", HUGE_INT],
    # batch
    "batch nothing": ["batch"],
    "batch no out": ["batch", "{txt}"],
    "batch empty manifest path": ["batch", "", "--out", "{out}"],
    "batch garbage manifest": ["batch", "{txt}", "--out", "{out}"],
    "batch workers zero": ["batch", "{txt}", "--out", "{out}", "--workers", "0"],
    "batch workers text": ["batch", "{txt}", "--out", "{out}", "--workers", "many"],
    "batch retries negative": ["batch", "{txt}", "--out", "{out}", "--retries", "-1"],
    "batch timeout nan": ["batch", "{txt}", "--out", "{out}", "--timeout", "nan"],
    "batch timeout zero": ["batch", "{txt}", "--out", "{out}", "--timeout", "0"],
    "batch graph without name": ["batch", "{txt}", "--out", "{out}", "--graph", "{graph}"],
    "batch graph empty path": ["batch", "{txt}", "--out", "{out}", "--graph", "small="],
    # demo
    "demo minutes nan": ["demo", "-o", "{out}", "--minutes", "nan"],
    "demo minutes zero": ["demo", "-o", "{out}", "--minutes", "0"],
    "demo minutes inf": ["demo", "-o", "{out}", "--minutes", BIG],
    "demo minutes huge": ["demo", "-o", "{out}", "--minutes", "1e300"],
    "demo seed text": ["demo", "-o", "{out}", "--seed", "x"],
    "demo layout unknown": ["demo", "-o", "{out}", "--layout", "elbows"],
    "demo output is a file": ["demo", "-o", "{txt}", "--minutes", "0.1"],
    # serve (before any graph loads)
    "serve no graph": ["serve"],
    "serve empty graph": ["serve", "--graph", "", "--port", "0"],
    "serve graph without name": ["serve", "--graph", "{graph}", "--port", "0"],
    "serve graph garbage": ["serve", "--graph", "g={txt}", "--port", "0"],
    "serve port text": ["serve", "--graph", "g={graph}", "--port", "http"],
    "serve max streams zero": ["serve", "--graph", "g={graph}", "--port", "0", "--max-streams", "0"],
    "serve max streams huge": ["serve", "--graph", "g={graph}", "--port", "0", "--max-streams", HUGE_INT],
    "serve message size nan": ["serve", "--graph", "g={graph}", "--port", "0", "--max-message-mb", "nan"],
    "serve message size inf": ["serve", "--graph", "g={graph}", "--port", "0", "--max-message-mb", BIG],
    "serve grace nan": ["serve", "--graph", "g={graph}", "--port", "0", "--grace-s", "nan"],
    "serve grace negative": ["serve", "--graph", "g={graph}", "--port", "0", "--grace-s", "-1"],
    "serve live workers negative": ["serve", "--graph", "g={graph}", "--port", "0", "--live-workers", "-1"],
    "serve live workers fraction": ["serve", "--graph", "g={graph}", "--port", "0", "--live-workers", "1.5"],
    "serve token file missing": ["serve", "--graph", "g={graph}", "--port", "0", "--token-file", "{dir}/t"],
    "serve token file empty": ["serve", "--graph", "g={graph}", "--port", "0", "--token-file", "{empty}"],
    "serve cert without key": ["serve", "--graph", "g={graph}", "--port", "0", "--tls-cert", "{txt}"],
    "serve batch dir missing": ["serve", "--graph", "g={graph}", "--port", "0", "--batch-dir", "{dir}/no"],
    "serve metrics port out of range": ["serve", "--graph", "g={graph}", "--port", "0", "--metrics-port", "70000"],
    "serve metrics port text": ["serve", "--graph", "g={graph}", "--port", "0", "--metrics-port", "http"],
    "serve batch workers zero": [
        "serve",
        "--graph",
        "g={graph}",
        "--port",
        "0",
        "--batch-dir",
        "{dir}",
        "--batch-workers",
        "0",
    ],
    # client
    "client nothing": ["client"],
    "client graphs empty server": ["client", "graphs", "--server", ""],
    "client graphs bad address": ["client", "graphs", "--server", "no such host:::1", "--timeout", "2"],
    "client graphs server list empty entry": ["client", "graphs", "--server", "{server},,{server}"],
    "client graphs server list without port": ["client", "graphs", "--server", "{server},127.0.0.1"],
    "client graphs timeout nan": ["client", "graphs", "--server", "{server}", "--timeout", "nan"],
    "client graphs timeout negative": ["client", "graphs", "--server", "{server}", "--timeout", "-1"],
    "client graphs timeout inf": ["client", "graphs", "--server", "{server}", "--timeout", BIG],
    "client graphs unknown graph": ["client", "graphs", "--server", "{server}", "--graph", "nope"],
    "client graphs token file missing": ["client", "graphs", "--server", "{server}", "--token-file", "{dir}/t"],
    "client graphs ca garbage": ["client", "graphs", "--server", "{server}", "--tls-ca", "{txt}", "--timeout", "2"],
    "client synthesize no output": ["client", "synthesize", "{rec}", *CLIENT],
    "client synthesize empty recording": ["client", "synthesize", "", "-o", "{out}.bvh", *CLIENT],
    "client synthesize garbage recording": ["client", "synthesize", "{txt}", "-o", "{out}.bvh", *CLIENT],
    "client synthesize weights nan": [*C_SYN, "--weights", "nan,1,1"],
    "client synthesize latency inf": [*C_SYN, "--latency", BIG],
    "client synthesize beam zero": [*C_SYN, "--beam", "0"],
    "client synthesize olng k huge": [*C_SYN, "--strategy", "olng", "--olng-k", HUGE_INT],
    "client synthesize unknown graph": [*C_SYN, "--graph", "nope"],
    "client stream speed nan": [*C_STREAM, "--speed", "nan"],
    "client stream speed zero": [*C_STREAM, "--speed", "0"],
    "client stream speed inf": [*C_STREAM, "--speed", BIG],
    "client stream latency negative": [*C_STREAM, "--latency", "-1"],
    "client stream vmc without port": [*C_STREAM, "--vmc", "127.0.0.1"],
    "client stream vmc port zero": [*C_STREAM, "--vmc", "127.0.0.1:0"],
    "client stream vmc unresolvable": [*C_STREAM, "--vmc", "no-such-host.invalid:39539"],
    "client stream garbage recording": ["client", "stream", "{txt}", *CLIENT],
    "client batch nothing": ["client", "batch"],
    "client batch submit missing manifest": ["client", "batch", "submit", "{dir}/m.csv", *CLIENT],
    "client batch status empty id": ["client", "batch", "status", "", *CLIENT],
    "client batch cancel path id": ["client", "batch", "cancel", "../x", *CLIENT],
    # sensor-bridge (checked before it opens the device or the server)
    "bridge no device": ["sensor-bridge", "--server", "{server}"],
    "bridge empty device": ["sensor-bridge", "--device", "", "--server", "{server}"],
    "bridge missing device": [*BRIDGE, "--timeout", "5"],
    "bridge baud zero": [*BRIDGE, "--baud", "0"],
    "bridge baud text": [*BRIDGE, "--baud", "fast"],
    "bridge duration nan": [*BRIDGE, "--duration", "nan"],
    "bridge duration negative": [*BRIDGE, "--duration", "-1"],
    "bridge calibrate seconds inf": [*BRIDGE, "--calibrate-seconds", BIG],
    "bridge weights nan": [*BRIDGE, "--weights", "nan,1,1"],
    "bridge vmc bad port": [*BRIDGE, "--vmc", "127.0.0.1:99999"],
}


@pytest.fixture(scope="module")
def files(tmp_path_factory, graph_file, rec_file, server):
    from graphsvc.motion.bvh import write_bvh
    from graphsvc.motion.procedural import generate_knowledge_base

    root = tmp_path_factory.mktemp("sweep")
    kb = root / "kb"
    kb.mkdir()
    for clip in generate_knowledge_base(seed=0, minutes=0.1)[:2]:
        write_bvh(kb / f"{clip.name}.bvh", clip, scale=100.0)
    txt = root / "notes.txt"
    txt.write_text("graphsvc reads none of this\n")
    (root / "empty.txt").write_text("")
    garbage = root / "garbage"
    for suffix in (".bvh", ".rec"):
        (root / f"garbage{suffix}").write_bytes(b"\x00\xffHIERARCHY nonsense\n" * 3)
    (root / "dir").mkdir()
    return {
        "graph": graph_file,
        "rec": rec_file,
        "clip": sorted(kb.glob("*.bvh"))[0],
        "kb": kb,
        "txt": txt,
        "empty": root / "empty.txt",
        "garbage": garbage,
        "dir": root / "dir",
        "server": f"127.0.0.1:{server.port}",
    }


def _answer(argv, capsys) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own refusals
        code = exc.code
    captured = capsys.readouterr()
    return code, captured.err


@pytest.mark.parametrize("name", list(CLI_CASES))
def test_cli_bad_argument_one_line_exit_2(name, files, capsys, tmp_path):
    argv = [a.format(**files, out=tmp_path / "out") for a in CLI_CASES[name]]
    code, err = _answer(argv, capsys)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, f"{name}: exit {code}, stderr {err!r}"
    assert len(lines) == 1 and lines[0].startswith("graphsvc: error: "), f"{name}: {err!r}"
    assert "Traceback" not in err
    assert list(tmp_path.iterdir()) == [], f"{name}: wrote {list(tmp_path.iterdir())}"


# ---------------------------------------------------------------- gRPC

INVALID = grpc.StatusCode.INVALID_ARGUMENT
INF, NAN = float("inf"), float("nan")


def _synth(*changes):
    """A request builder: the recording as a SynthesizeRequest for graph small, then
    each change (a function of the request) applied."""

    def build(recording):
        request = pb.SynthesizeRequest(graph="small", recording=convert.recording_to_proto(recording))
        for change in changes:
            change(request)
        return request

    return build


def _set(path: str, value):
    def change(msg):
        *parents, last = path.split(".")
        for p in parents:
            msg = getattr(msg, p)
        if callable(value):
            getattr(msg, last)[:] = value(len(getattr(msg, last)))
        elif isinstance(value, list):
            del getattr(msg, last)[:]
            getattr(msg, last).extend(value)
        else:
            setattr(msg, last, value)

    return change


def _fixed(request):
    return lambda recording: request


UNARY_CASES = {
    "GetGraph empty": ("GetGraph", _fixed(pb.GetGraphRequest(name="")), INVALID, "name"),
    "GetGraph unknown": ("GetGraph", _fixed(pb.GetGraphRequest(name="nope")), grpc.StatusCode.NOT_FOUND, "nope"),
    "GetGraph oversize name": (
        "GetGraph",
        _fixed(pb.GetGraphRequest(name="x" * 100_000)),
        grpc.StatusCode.NOT_FOUND,
        "graph",
    ),
    "Synthesize empty": ("Synthesize", _fixed(pb.SynthesizeRequest()), INVALID, "graph"),
    "Synthesize no recording": ("Synthesize", _fixed(pb.SynthesizeRequest(graph="small")), INVALID, "recording"),
    "rate inf": ("Synthesize", _synth(_set("recording.rate_hz", INF)), INVALID, "rate_hz"),
    "rate huge": ("Synthesize", _synth(_set("recording.rate_hz", 1e300)), INVALID, "rate_hz"),
    "rate negative": ("Synthesize", _synth(_set("recording.rate_hz", -30.0)), INVALID, "rate_hz"),
    "times inf": (
        "Synthesize",
        _synth(_set("recording.timestamps_s", lambda n: [0.0, INF] + [9.0] * (n - 2))),
        INVALID,
        "timestamps_s",
    ),
    "times huge": (
        "Synthesize",
        _synth(_set("recording.timestamps_s", lambda n: [k * 1e12 for k in range(n)])),
        INVALID,
        "timestamps_s",
    ),
    "headings inf": (
        "Synthesize",
        _synth(_set("recording.headings_rad", lambda n: [INF] * n)),
        INVALID,
        "headings_rad",
    ),
    "orientations short": (
        "Synthesize",
        _synth(_set("recording.orientations_wxyz", [1.0] * 7)),
        INVALID,
        "orientations_wxyz",
    ),
    "markers without names": (
        "Synthesize",
        _synth(_set("recording.marker_positions_m", [0.0] * 3)),
        INVALID,
        "marker_positions_m",
    ),
    "latency inf": ("Synthesize", _synth(_set("options.latency_s", INF)), INVALID, "latency_s"),
    "latency negative": ("Synthesize", _synth(_set("options.latency_s", -1.0)), INVALID, "latency_s"),
    "beam inf": ("Synthesize", _synth(_set("options.beam", INF)), INVALID, "beam"),
    "beam nan": ("Synthesize", _synth(_set("options.beam", NAN)), INVALID, "beam"),
    "weight inf": ("Synthesize", _synth(_set("options.weights.acceleration", INF)), INVALID, "weights"),
    "track pull nan": ("Synthesize", _synth(_set("options.viterbi.track_pull_s", NAN)), INVALID, "track_pull"),
    "rest heading inf": ("Synthesize", _synth(_set("options.rest_heading_deg", INF)), INVALID, "rest_heading"),
    "speed threshold nan": ("Synthesize", _synth(_set("options.speed_threshold_m_s", NAN)), INVALID, "speed_threshold"),
    "strategy out of range": ("Synthesize", _synth(_set("options.strategy", 99)), INVALID, "strategy"),
    "olng k huge": (
        "Synthesize",
        _synth(_set("options.strategy", pb.STRATEGY_OLNG), _set("options.olng.k", 2**31 - 1)),
        INVALID,
        "OLNG K",
    ),
    "olng weight nan": (
        "Synthesize",
        _synth(_set("options.strategy", pb.STRATEGY_OLNG), _set("options.olng.w_prior", NAN)),
        INVALID,
        "olng",
    ),
    "ssg window inf": (
        "Synthesize",
        _synth(
            _set("options.strategy", pb.STRATEGY_SSG),
            _set("options.ssg.markers", "hands-feet"),
            _set("options.ssg.window_s", INF),
        ),
        INVALID,
        "ssg",
    ),
    "constraint end inf": (
        "Synthesize",
        _synth(lambda r: r.options.constraint_sets.add().constraints.add(start_s=0.0, end_s=INF, label="walk")),
        INVALID,
        "constraint",
    ),
    "GetBatch without a batch folder": (
        "GetBatch",
        _fixed(pb.GetBatchRequest(batch_id="x")),
        grpc.StatusCode.FAILED_PRECONDITION,
        "batch",
    ),
    "SubmitBatch without a batch folder": (
        "SubmitBatch",
        _fixed(pb.SubmitBatchRequest(manifest="a")),
        grpc.StatusCode.FAILED_PRECONDITION,
        "batch",
    ),
    "CancelBatch without a batch folder": (
        "CancelBatch",
        _fixed(pb.CancelBatchRequest(batch_id="")),
        grpc.StatusCode.FAILED_PRECONDITION,
        "batch",
    ),
}


@pytest.mark.parametrize("name", list(UNARY_CASES))
def test_grpc_unary_bad_argument_gets_its_status(name, conn, recording):
    method, build, code, mention = UNARY_CASES[name]
    got, details = rpc_error(getattr(conn.stub, method), build(recording), timeout=20)
    assert got == code, f"{name}: {got} {details}"
    assert mention in details, f"{name}: {details!r} does not name {mention!r}"


def _samples(recording, n=4, **changes):
    out = list(C.recording_samples(recording))[:n]
    for key, value in changes.items():
        index, field = key.split("_", 1)
        sample = out[int(index[1:])]
        if isinstance(value, list):
            del getattr(sample, field)[:]
            getattr(sample, field).extend(value)
        else:
            setattr(sample, field, value)
    return out


def _with(samples, change):
    change(samples)
    return samples


STREAM_CASES = {
    "empty config": (lambda rec: [pb.StreamSynthesizeRequest(config=pb.StreamConfig())], INVALID, "graph"),
    "oversize graph name": (
        lambda rec: _requests(C.stream_config("x" * 100_000), _samples(rec)),
        grpc.StatusCode.NOT_FOUND,
        "graph",
    ),
    "latency inf": (
        lambda rec: _requests(C.stream_config("small", pb.SynthesisOptions(latency_s=INF)), _samples(rec)),
        INVALID,
        "latency_s",
    ),
    "beam nan": (
        lambda rec: _requests(C.stream_config("small", pb.SynthesisOptions(beam=NAN)), _samples(rec)),
        INVALID,
        "beam",
    ),
    "strategy out of range": (
        lambda rec: _requests(C.stream_config("small", pb.SynthesisOptions(strategy=42)), _samples(rec)),
        INVALID,
        "strategy",
    ),
    "time nan": (
        lambda rec: _requests(C.stream_config("small"), _samples(rec, s1_time_s=NAN)),
        INVALID,
        "sample[1].time_s",
    ),
    "time inf": (
        lambda rec: _requests(C.stream_config("small"), _samples(rec, s2_time_s=INF)),
        INVALID,
        "sample[2].time_s",
    ),
    "time huge jump": (
        lambda rec: _requests(C.stream_config("small"), _samples(rec, s2_time_s=1e300)),
        INVALID,
        "sample[2].time_s",
    ),
    "position inf": (
        lambda rec: _requests(
            C.stream_config("small"), _with(_samples(rec), lambda s: s[0].ground_position.__setattr__("x_m", INF))
        ),
        INVALID,
        "sample[0]",
    ),
    "heading inf": (
        lambda rec: _requests(C.stream_config("small"), _samples(rec, s0_heading_rad=INF)),
        INVALID,
        "sample[0]",
    ),
    "oversize sample": (
        lambda rec: _requests(C.stream_config("small"), _samples(rec, s0_accelerations_m_s2=[0.0] * 300_000)),
        INVALID,
        "sample[0].accelerations_m_s2",
    ),
    "empty sample": (lambda rec: _requests(C.stream_config("small"), [pb.SensorSample()]), INVALID, "sample[0]"),
}


@pytest.mark.parametrize("name", list(STREAM_CASES))
def test_grpc_stream_bad_argument_gets_its_status(name, conn, server, recording):
    build, code, mention = STREAM_CASES[name]
    requests = list(build(recording))
    got, details = rpc_error(lambda: list(conn.stub.StreamSynthesize(iter(requests), timeout=20)))
    assert got == code, f"{name}: {got} {details}"
    assert mention in details, f"{name}: {details!r} does not name {mention!r}"


def test_grpc_garbage_bytes_and_the_server_still_serves(conn, server, recording):
    """Bytes that are no message of the method: INVALID_ARGUMENT (gRPC's own decoding
    answers INTERNAL for a message it cannot parse), never a dead server."""
    channel = grpc.insecure_channel(f"127.0.0.1:{server.port}")
    try:
        for method in ("GetGraph", "Synthesize"):
            call = channel.unary_unary(
                f"/graphsvc.v1.MotionGraphService/{method}",
                request_serializer=lambda b: b,
                response_deserializer=lambda b: b,
            )
            with pytest.raises(grpc.RpcError) as info:
                call(b"\xff\xff\xff\xff garbage", timeout=10)
            assert info.value.code() in (grpc.StatusCode.INTERNAL, INVALID), method
    finally:
        channel.close()
    assert C.synthesize(conn, "small", recording).motion.num_frames == recording.num_samples


@pytest.fixture(scope="module")
def batch_server(loaded_graphs, tmp_path_factory):
    from tests.service.conftest import start

    running = start(loaded_graphs, batch_dir=tmp_path_factory.mktemp("batches"))
    yield running
    running.stop(0)


BATCH_CASES = {
    "submit empty": ("SubmitBatch", pb.SubmitBatchRequest(manifest=""), INVALID, "manifest"),
    "submit garbage": ("SubmitBatch", pb.SubmitBatchRequest(manifest="\x00\x01 not a manifest"), INVALID, "manifest"),
    "submit format unknown": (
        "SubmitBatch",
        pb.SubmitBatchRequest(manifest="a,b\n1,2\n", format="xml"),
        INVALID,
        "format",
    ),
    "submit oversize": (
        "SubmitBatch",
        pb.SubmitBatchRequest(manifest="recording,graph,strategy,output\n" + "x.rec,small,viterbi,o\n" * 100_000),
        INVALID,
        "manifest",
    ),
    "submit retries negative": (
        "SubmitBatch",
        pb.SubmitBatchRequest(manifest="recording,graph,strategy,output\nx.rec,small,viterbi,o\n", retries=-1),
        INVALID,
        "retries",
    ),
    "get empty id": ("GetBatch", pb.GetBatchRequest(batch_id=""), grpc.StatusCode.NOT_FOUND, "batch_id"),
    "get path id": ("GetBatch", pb.GetBatchRequest(batch_id="../../etc"), grpc.StatusCode.NOT_FOUND, "batch_id"),
    "get oversize id": ("GetBatch", pb.GetBatchRequest(batch_id="x" * 100_000), grpc.StatusCode.NOT_FOUND, "batch_id"),
    "cancel unknown": ("CancelBatch", pb.CancelBatchRequest(batch_id="nope"), grpc.StatusCode.NOT_FOUND, "batch_id"),
}


@pytest.mark.parametrize("name", list(BATCH_CASES))
def test_grpc_batch_bad_argument_gets_its_status(name, batch_server):
    method, request, code, mention = BATCH_CASES[name]
    with C.connect(f"127.0.0.1:{batch_server.port}") as conn:
        got, details = rpc_error(getattr(conn.stub, method), request, timeout=20)
    assert got == code, f"{name}: {got} {details}"
    assert mention in details, f"{name}: {details!r} does not name {mention!r}"
