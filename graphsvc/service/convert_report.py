"""Reports and statuses ↔ protocol buffers: a reconstruction's report in a
SynthesizeResponse (JSON text and Struct), a batch's `BatchStatus`, and the values a
`google.protobuf.Struct` can hold (`json_safe`, `struct_to_dict`).
"""

from __future__ import annotations

import json
import math

import numpy as np

from graphsvc.errors import InputError
from graphsvc.service._generated import graphsvc_pb2 as pb


def json_safe(value):
    """A JSON-able copy for google.protobuf.Struct: numpy scalars and arrays become
    Python numbers and lists, NaN and ±inf become None (Struct cannot print them)."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if value is None or isinstance(value, str):
        return value
    return str(value)


def report_to_proto(report: dict, response: pb.SynthesizeResponse) -> None:
    """The report into a SynthesizeResponse: JSON text (report_json, types kept) and
    the Struct (report, every number a double) for clients that read that."""
    safe = json_safe(report)
    response.report_json = json.dumps(safe, sort_keys=True, allow_nan=False)
    response.report.update(safe)


def report_from_proto(response: pb.SynthesizeResponse) -> dict:
    """The report of a SynthesizeResponse with its integers as integers (from
    report_json; a server that sends only the Struct gives its doubles)."""
    if response.report_json:
        try:
            report = json.loads(response.report_json)
        except json.JSONDecodeError as exc:
            raise InputError(f"report_json: not valid JSON ({exc.msg})") from None
        if isinstance(report, dict):
            return report
    return struct_to_dict(response.report)


def struct_to_dict(msg) -> dict:
    from google.protobuf.json_format import MessageToDict

    return MessageToDict(msg)


def batch_status_to_proto(status: dict) -> pb.BatchStatus:
    """A BatchManager status (batch.service) as a BatchStatus."""
    msg = pb.BatchStatus(
        batch_id=status["batch_id"],
        state=status["state"],
        items=status["items"],
        queued=status["queued"],
        running=status["running"],
        done=status["done"],
        failed=status["failed"],
        error=status["error"],
        submitted_unix_s=status["submitted"],
        folder=status["folder"],
    )
    for r in status.get("item_rows", ()):
        res = r["result"] or {}
        msg.item_status.append(
            pb.BatchItem(
                output=r["output"],
                line=r["line"] or 0,
                state=r["state"],
                attempts=r["attempts"] or 0,
                reason=r["reason"] or "",
                seconds=res.get("seconds", 0.0),
                output_path=r["output_path"] or "",
                checksum=r["checksum"] or "",
            )
        )
    return msg
