"""Commands that call a graphsvc server: `client graphs|synthesize|stream|batch` and
`sensor-bridge` (a serial accelerometer device streamed to a server)."""

from __future__ import annotations

import argparse
import json
import signal
import threading
import time
from pathlib import Path

from graphsvc.cli.args import command, print_flushed, print_notes
from graphsvc.errors import GraphsvcError
from graphsvc.fileio import check_outputs, read_input_text
from graphsvc.flags import (
    PATH,
    add_calibrate_from_start_flags,
    add_calibration_flag,
    add_input_file_flags,
    add_performer_flags,
    add_search_flags,
    calibration_choice,
    options_from_flags,
    ranged,
    synthesize_inputs,
)


def _check_output(path: Path, inputs=()) -> None:
    """A motion output: its folder there, .bvh, .glb or .gltf, none of the inputs (`fileio.check_outputs`)."""
    from graphsvc.motion.output import MOTION_OUTPUT_SUFFIXES

    check_outputs([("-o", path, MOTION_OUTPUT_SUFFIXES)], inputs)


def _connect(args):
    from graphsvc.service.client import connect, read_token_file

    token = read_token_file(args.token_file) if args.token_file else None
    return connect(args.server, token=token, tls_ca=args.tls_ca, tls_server_name=args.tls_server_name)


def _options(args, constraints=None, recording=None):
    """SynthesisOptions from the strategy flags (`graphsvc.flags.options_from_flags`), for
    `recording` when given (the strategy's `options_for_recording`: what the recording
    decides locally, such as SSG's marker set and offsets; a marker set file is sent as
    its content)."""
    from graphsvc.service.convert import options_to_proto

    options, notes = options_from_flags(args)
    print_notes(notes)
    return options_to_proto(options, constraints, recording)


def _recording(args, info):
    """The recording as the client sends it to the server's graph `info`: read (--up,
    --units), a device's sensors named as the graph's layout does (--device-map), in
    the layout's sensor frames with --calibration (`pipeline.read_recording_file`);
    its notes printed."""
    from graphsvc.pipeline import read_recording_file

    notes = []
    try:
        return read_recording_file(
            args.recording,
            args.up,
            args.units,
            args.device_map,
            args.calibration,
            notes,
            layout_name=info.layout,
            sensor_names=tuple(info.sensor_names),
        )
    finally:
        print_notes(notes)


def _cmd_client_graphs(args) -> int:
    from graphsvc.graph.model import format_summary
    from graphsvc.service.client import get_graph, list_graphs
    from graphsvc.service.convert import graph_info_dict

    with _connect(args) as conn:
        if args.graph:
            info = graph_info_dict(get_graph(conn, args.graph, args.timeout))
            print(json.dumps(info, indent=2, sort_keys=True) if args.json else format_summary(info))
            return 0
        graphs = list_graphs(conn, args.timeout)
    if args.json:
        print(json.dumps({g.name: graph_info_dict(g) for g in graphs}, indent=2, sort_keys=True))
        return 0
    for g in graphs:
        print(
            f"{g.name}: {g.node_count:,} nodes, {g.edge_count:,} edges, {g.rate_hz:g} Hz, "
            f"layout {g.layout} ({', '.join(g.sensor_names)}), {g.kb_minutes:.1f} min of motion"
        )
    return 0


def _cmd_client_synthesize(args) -> int:
    from graphsvc.fileio import write_texts_atomic
    from graphsvc.motion.output import MOTION_OUTPUT_SUFFIXES, motion_file_bytes, output_format
    from graphsvc.service.client import resolve_graph, synthesize
    from graphsvc.service.convert import skeleton_from_proto

    out = Path(args.output)
    check_outputs([("-o", out, MOTION_OUTPUT_SUFFIXES), ("--report", args.report, (".json",))], synthesize_inputs(args))
    _, start_s, pose = calibration_choice(args)
    performer = _performer(args)
    with _connect(args) as conn:
        info = resolve_graph(conn, args.graph, args.timeout)
        rec = _recording(args, info)
        options = _options(args, rec.constraints, rec)
        result = synthesize(
            conn,
            info.name,
            rec,
            options,
            timeout_s=args.timeout,
            skeleton=skeleton_from_proto(info.skeleton),
            calibrate_from_start=None if start_s is None else (start_s, pose),
            performer=performer,
        )
    # The server's BVH as it sent it (centimetres); glTF from the returned motion.
    data = result.bvh if output_format(out) == "bvh" else motion_file_bytes(out, result.motion)
    report = [(args.report, json.dumps(result.report, indent=1, sort_keys=True) + "\n")] if args.report else []
    write_texts_atomic(report + [(out, data)])
    r = result.report
    timings = r.get("timings_s", {})
    print(
        f"wrote {out}: {result.motion.num_frames} frames at {info.rate_hz:g} Hz from {rec.num_samples} samples, "
        f"graph {info.name} on {args.server} ({r.get('strategy', args.strategy)}, "
        f"search {timings.get('search', float('nan')):.2f} s)"
    )
    return 0


def _performer(args):
    """The `Performer` of --height or --performer (a performer file's segments, read
    here: the server reads no files), or None."""
    from graphsvc.errors import InputError
    from graphsvc.motion.proportions import check_height, performer_segments
    from graphsvc.service.convert import performer_to_proto

    if args.height is not None:
        return performer_to_proto(height_m=check_height(args.height))
    if args.performer is not None:
        return performer_to_proto(segments_m=performer_segments(args.performer, args.performer_mapping))
    if args.performer_mapping is not None:
        raise InputError("--performer-mapping applies to a --performer motion file")
    return None


def _batch_line(b) -> str:
    line = (
        f"{b.batch_id}: {b.state}, {b.items} items: {b.done} done, {b.failed} failed, {b.running} running, "
        f"{b.queued} queued"
    )
    return line + (f" — {b.error}" if b.error else "")


def _cmd_client_batch(args) -> int:
    from google.protobuf.json_format import MessageToDict

    from graphsvc.service._generated import graphsvc_pb2 as pb
    from graphsvc.service.client import batch_call, submit_batch

    with _connect(args) as conn:
        if args.batch_command == "submit":
            path = Path(args.manifest)
            fmt = args.format or ("json" if path.suffix.lower() == ".json" else "csv")
            status = submit_batch(conn, read_input_text(path, "manifest"), fmt, args.retries, args.timeout)
            while args.wait and status.state in ("queued", "running"):
                time.sleep(args.poll)
                status = batch_call(conn, "GetBatch", pb.GetBatchRequest(batch_id=status.batch_id), args.timeout)
        elif args.batch_command == "status":
            status = batch_call(
                conn, "GetBatch", pb.GetBatchRequest(batch_id=args.batch_id, items=args.items), args.timeout
            )
        elif args.batch_command == "cancel":
            status = batch_call(conn, "CancelBatch", pb.CancelBatchRequest(batch_id=args.batch_id), args.timeout)
        else:
            batches = batch_call(conn, "ListBatches", pb.ListBatchesRequest(), args.timeout).batches
            if args.json:
                print(json.dumps([MessageToDict(b, preserving_proto_field_name=True) for b in batches], indent=1))
            for b in [] if args.json else batches:
                print(_batch_line(b))
            return 0
    if getattr(args, "json", False):
        print(
            json.dumps(
                MessageToDict(status, preserving_proto_field_name=True, always_print_fields_with_no_presence=True),
                indent=1,
                sort_keys=True,
            )
        )
    else:
        print(_batch_line(status))
        for item in status.item_status:
            print(
                f"  {item.output} (line {item.line}): {item.state}, {item.attempts} attempt(s)"
                + (f", {item.seconds:.2f} s, {item.output_path}" if item.state == "done" else "")
                + (f" — {item.reason}" if item.reason else "")
            )
    return 1 if status.failed or status.state == "error" else 0


def _cmd_client_stream(args) -> int:
    from graphsvc.motion.output import write_motion
    from graphsvc.service.client import latency_summary, resolve_graph, stream_recording

    out = Path(args.output) if args.output else None
    if out is not None:
        _check_output(out, synthesize_inputs(args))
    _, start_s, pose = calibration_choice(args)
    _vmc_address(args)
    vmc = None

    def on_frame(frame, latency_ms):
        if vmc is not None:
            vmc.send(frame)
        if not args.quiet:
            print_flushed(
                f"frame {frame.index:6d}  t {frame.time_s:8.3f} s  node {frame.node:7d}  {frame.label:<10s}"
                f"  latency {latency_ms:7.2f} ms"
            )

    with _connect(args) as conn:
        info = resolve_graph(conn, args.graph, args.timeout)
        vmc = _vmc_sender(args, info)
        rec = _recording(args, info)
        options = _options(args, recording=rec)
        result = stream_recording(
            conn,
            info.name,
            rec,
            options,
            speed=args.speed,
            on_frame=on_frame,
            calibrate_from_start=None if start_s is None else (start_s, pose),
        )
    s = latency_summary(result.latencies_ms)
    lag = result.started.lag_frames if result.started else 0
    print(
        f"{s['frames']} frames from {rec.num_samples} samples; latency beyond the lag of {lag} frames "
        f"({lag / info.rate_hz:.2f} s): p50 {s['p50_ms']} ms, p99 {s['p99_ms']} ms, max {s['max_ms']} ms"
        + (f"; server {result.server}" if result.server else "")
    )
    if vmc is not None:
        print(vmc.summary())
    if out is not None:
        write_motion(out, result.motion(), scale=100.0)
        print(f"wrote {out}")
    return 0


def _vmc_address(args) -> None:
    """--vmc checked before anything connects (one line, exit 2 when malformed)."""
    if getattr(args, "vmc", None) is not None:
        from graphsvc.service.vmc import parse_vmc_address

        parse_vmc_address(args.vmc)


def _vmc_sender(args, info):
    """The VMC sender of --vmc for the server graph `info`'s skeleton, or None."""
    if getattr(args, "vmc", None) is None:
        return None
    from graphsvc.service.convert_graph import skeleton_from_proto
    from graphsvc.service.vmc import VmcSender

    return VmcSender(args.vmc, skeleton_from_proto(info.skeleton))


def _add_vmc_flag(p) -> None:
    p.add_argument(
        "--vmc",
        metavar="HOST:PORT",
        help="also send each pose frame as it arrives to a VMC receiver (OSC over UDP: VSeeFace, EVMC4U, "
        "VMC4UE, VMC4B; e.g. 127.0.0.1:39539), Unity humanoid bones (default: none; docs/service.md)",
    )


def _cmd_sensor_bridge(args) -> int:
    import serial

    from graphsvc.motion.output import write_motion
    from graphsvc.service.bridge import run_bridge
    from graphsvc.service.client import resolve_graph

    out = Path(args.output) if args.output else None
    if out is not None:
        _check_output(out, [("the calibration", args.calibration), ("the constraints", args.constraints)])
    if args.calibrate_seconds < 0:
        raise GraphsvcError(f"--calibrate-seconds must be ≥ 0, got {args.calibrate_seconds}")
    _vmc_address(args)
    options = _options(args)
    cal = None
    if args.calibration:
        from graphsvc.sensors.calibration import calibration_rotations, load_calibration

        cal = load_calibration(args.calibration)
    stop = threading.Event()
    with _connect(args) as conn:
        info = resolve_graph(conn, args.graph, args.timeout)
        mounting = None if cal is None else calibration_rotations(cal, tuple(info.sensor_names))
        vmc = _vmc_sender(args, info)
        try:
            port = serial.Serial(args.device, args.baud, timeout=0.1)
        except (serial.SerialException, ValueError) as exc:
            raise GraphsvcError(f"cannot open {args.device}: {exc}") from None
        previous = {}
        if threading.current_thread() is threading.main_thread():
            # Ctrl-C / SIGTERM end the input; the server's last frames still arrive.
            previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            print_flushed(
                f"sensor-bridge: reading {args.device} at {args.baud} baud ({args.units}), streaming to "
                f"{args.server} graph {info.name} ({', '.join(info.sensor_names)} at {info.rate_hz:g} Hz)"
                + (
                    f"; calibrating for {args.calibrate_seconds:g} s: stand still in the rest pose"
                    if args.calibrate_seconds
                    else ""
                )
            )
            result = run_bridge(
                port,
                conn,
                info,
                options,
                args.units,
                args.calibrate_seconds,
                stop,
                args.duration,
                on_frame=None if vmc is None else vmc.send,
                mounting=mounting,
            )
        finally:
            port.close()
            for s, handler in previous.items():
                signal.signal(s, handler)
    st = result.stats
    reasons = ", ".join(f"{n} {r}" for r, n in sorted(st.corrupt.items()))
    print_flushed(
        f"sensor-bridge: {result.end_reason}; {st.lines} lines, {st.corrupt_lines} corrupt skipped"
        + (f" ({reasons})" if reasons else "")
        + f"; {st.device_samples} device samples ({st.incomplete_samples} incomplete, "
        f"{st.calibration_samples} calibrating) → {st.samples_streamed} samples at {info.rate_hz:g} Hz; "
        f"{len(result.stream.frames)} frames"
    )
    if result.calibration is not None:
        cal = result.calibration
        bias = "; ".join(f"{n} ({', '.join(f'{v:+.2f}' for v in b)})" for n, b in zip(info.sensor_names, cal.bias))
        print_flushed(f"sensor-bridge: calibration bias m/s²: {bias}")
        for w in cal.warnings:
            print_flushed(f"sensor-bridge: warning: {w}")
    if vmc is not None:
        print_flushed(f"sensor-bridge: {vmc.summary()}")
    if out is not None:
        if not result.stream.frames:
            raise GraphsvcError(f"no frames came back; {out} not written")
        write_motion(out, result.stream.motion(), scale=100.0)
        print_flushed(f"wrote {out}: {len(result.stream.frames)} frames")
    return 0


# ---------------------------------------------------------------- parsers


def _connection_parent() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument(
        "--server",
        default="127.0.0.1:50051",
        metavar="ADDR",
        help="HOST:PORT, or several as HOST:PORT,HOST:PORT,... (each call to the next server that answers, "
        "gRPC's round_robin; a stream stays on its server), or a gRPC target such as "
        "dns:///NAME:PORT (default 127.0.0.1:50051)",
    )
    p.add_argument("--graph", metavar="NAME", help="graph name on the server (default: its only graph)")
    p.add_argument("--token-file", metavar="F", type=PATH, help="file holding the bearer token (default: send none)")
    p.add_argument(
        "--tls-ca", metavar="F", type=PATH, help="PEM CA certificate of the server: use TLS (default: plaintext)"
    )
    p.add_argument(
        "--tls-server-name",
        metavar="NAME",
        help="name to check the server certificate against (default: the host of --server)",
    )
    p.add_argument(
        "--timeout",
        type=float,
        metavar="S",
        help="deadline of each unary call (graph lookup, synthesize, batches), seconds; a live stream has "
        "none (default: none)",
    )
    return p


def _live_latency_help(coda: str = "") -> str:
    """--latency of the live commands: what the lag is, from each strategy's own account
    (`Strategy.describe_lag`, at 30 Hz)."""
    from graphsvc.strategies import available, get
    from graphsvc.strategies.live import LiveSession

    lags = "; ".join(f"{name}'s {get(name).describe_lag(30.0)}" for name in available())
    return (
        f"the search's fixed lag, seconds: it settles a frame S s after the frame's sample (default "
        f"{LiveSession.DEFAULT_LATENCY_S:g}). The pose comes out later: {lags}" + coda
    )


def _json_flag(p, what: str) -> None:
    p.add_argument("--json", action="store_true", help=f"print {what} as JSON (default: as text)")


def add_client(sub) -> None:
    """`client` and its subcommands: graphs, synthesize, batch …, stream."""
    connection = _connection_parent()
    p = command(
        sub,
        "client",
        "call a graphsvc server",
        "Call a graphsvc server (graphsvc serve): list its graphs, reconstruct a recording, replay one live, "
        "run batches.",
    )
    client = p.add_subparsers(dest="client_command", required=True, parser_class=type(p), help="what to call")

    what = "list the server's graphs (--graph: one in full)"
    c = client.add_parser(
        "graphs",
        parents=[connection],
        help=what,
        description=(
            "List the server's graphs, one line each; with --graph NAME, that graph in full, as `graphsvc info` "
            "prints it."
        ),
    )
    _json_flag(c, "the graphs (with --graph: that graph)")
    c.set_defaults(run=_cmd_client_graphs)

    what = "reconstruct a recording on the server"
    c = client.add_parser(
        "synthesize",
        parents=[connection],
        help=what,
        description=(
            "Reconstruct a recording on the server (Synthesize, the whole recording at once) and write the motion as "
            "BVH; the recording's own constraint sets are sent unless --constraints replaces them."
        ),
    )
    c.add_argument("recording", metavar="REC", type=PATH, help="recording (.rec, device CSV or Xsens MVNX)")
    c.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="OUT.bvh",
        type=PATH,
        help="the motion to write: .bvh (cm), .glb or .gltf (required)",
    )
    c.add_argument("--report", metavar="OUT.json", type=PATH, help="write the search report (default: none)")
    add_input_file_flags(c)
    add_calibration_flag(c)
    add_calibrate_from_start_flags(c)
    add_search_flags(c)
    add_performer_flags(c)
    c.set_defaults(run=_cmd_client_synthesize)

    what = "batches on the server: submit, status, list, cancel"
    c = client.add_parser(
        "batch",
        help=what,
        description=(
            "Batches of recordings on the server's files, run on its Dask cluster (a server started with --batch-dir; "
            "docs/batch.md): submit, status, list, cancel."
        ),
    )
    batch = c.add_subparsers(dest="batch_command", required=True, parser_class=type(p), help="what to do")
    what = "submit a manifest (its paths: the server's files)"
    b = batch.add_parser(
        "submit",
        parents=[connection],
        help=what,
        description=(
            "Submit a manifest of recordings to reconstruct; its paths are the server's files. Prints the batch's "
            "state (with --wait: once it ends; exit 1 if any item failed)."
        ),
    )
    b.add_argument("manifest", metavar="MANIFEST", type=PATH, help="CSV or JSON manifest (docs/batch.md)")
    b.add_argument(
        "--format",
        choices=("csv", "json"),
        help="the manifest's format (default: by the file's extension, csv unless .json)",
    )
    b.add_argument("--retries", type=int, metavar="R", help="further attempts after a worker's failure (default 2)")
    b.add_argument("--wait", action="store_true", help="poll until the batch ends (default: return once submitted)")
    b.add_argument(
        "--poll", type=float, default=2.0, metavar="S", help="with --wait: seconds between polls (default 2)"
    )
    _json_flag(b, "the batch's status")
    what = "a batch's state and counts"
    b = batch.add_parser(
        "status",
        parents=[connection],
        help=what,
        description=("Print a batch's state and item counts (exit 1 if any item failed)."),
    )
    b.add_argument("batch_id", metavar="ID", help="the batch's id (as submit printed it)")
    b.add_argument(
        "--items", action="store_true", help="every item's state, attempts and reason (default: counts only)"
    )
    _json_flag(b, "the batch's status")
    what = "the server's batches, newest first"
    b = batch.add_parser(
        "list", parents=[connection], help=what, description=("List the server's batches, newest first, one line each.")
    )
    _json_flag(b, "the batches")
    what = "stop a batch (its unfinished items queued)"
    b = batch.add_parser(
        "cancel",
        parents=[connection],
        help=what,
        description=(
            "Stop a running batch (its unfinished items are left queued, to resume with `graphsvc batch`) and print "
            "its status."
        ),
    )
    b.add_argument("batch_id", metavar="ID", help="the batch's id (as submit printed it)")
    _json_flag(b, "the batch's status")
    c.set_defaults(run=_cmd_client_batch)

    what = "replay a recording live and print per-frame latency"
    c = client.add_parser(
        "stream",
        parents=[connection],
        help=what,
        description=(
            "Replay a recording live through StreamSynthesize, in real time or --speed times faster; print one line per "
            "frame with its latency (receipt minus sending of the sample that released it), then p50/p99/max beyond "
            "the stream's lag, which the summary states."
        ),
    )
    c.add_argument("recording", metavar="REC", type=PATH, help="recording to replay (.rec, device CSV or Xsens MVNX)")
    c.add_argument(
        "--speed",
        type=ranged(float, 0.0, 1e6, low_open=True),
        default=1.0,
        metavar="X",
        help="replay X times faster than real time (default 1: real time)",
    )
    c.add_argument(
        "-o",
        "--output",
        metavar="OUT.bvh",
        type=PATH,
        help="write the streamed motion: .bvh (cm), .glb or .gltf (default: none)",
    )
    c.add_argument("--quiet", action="store_true", help="only the summary, no line per frame (default: a line each)")
    add_input_file_flags(c)
    add_calibration_flag(c)
    add_calibrate_from_start_flags(c)
    _add_vmc_flag(c)
    add_search_flags(c, latency_help=_live_latency_help(". The summary names the stream's lag"))
    c.set_defaults(run=_cmd_client_stream)


def add_sensor_bridge(sub) -> None:
    p = command(
        sub,
        "sensor-bridge",
        "stream a serial accelerometer device to a server",
        "Read accelerometer lines (t_ms,sensor_id,ax,ay,az) from a serial device, resample them to the graph "
        "rate, stream them to a server and write the motion that comes back; ends when the device closes, "
        "after --duration, or on Ctrl-C/SIGTERM (docs/service.md, Serial sensor bridge).",
        parents=[_connection_parent()],
    )
    p.add_argument(
        "--device", required=True, metavar="DEV", type=PATH, help="serial device, e.g. /dev/ttyUSB0 (required)"
    )
    p.add_argument("--baud", type=int, default=115200, metavar="B", help="baud rate (default 115200)")
    p.add_argument(
        "--units", choices=("m/s2", "g"), default="m/s2", help="units of the device's readings (default m/s2)"
    )
    p.add_argument(
        "--calibrate-seconds",
        type=float,
        default=0.0,
        metavar="S",
        help="stand still in the rest pose for the first S seconds to estimate sensor biases (default 0: "
        "no bias estimated)",
    )
    p.add_argument(
        "--duration", type=float, metavar="S", help="stop after S seconds (default: until the device closes)"
    )
    p.add_argument(
        "-o",
        "--output",
        metavar="OUT.bvh",
        type=PATH,
        help="write the returned motion: .bvh (cm), .glb or .gltf (default: none)",
    )
    add_calibration_flag(p)
    _add_vmc_flag(p)
    add_search_flags(p, latency_help=_live_latency_help())
    p.set_defaults(run=_cmd_sensor_bridge)
