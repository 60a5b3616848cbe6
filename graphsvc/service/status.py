"""Failures → gRPC status: `RpcStatus` (a status a handler ends its call with),
`abort_for` (every exception a handler catches, to exactly one status) and
`status_details` (a status message cut to what a trailer carries).

INVALID_ARGUMENT for graphsvc's errors (a FieldError names the offending field);
UNIMPLEMENTED for a strategy not built; UNAVAILABLE for a stream whose live worker
died; CANCELLED for a search stopped because the client is gone or out of time;
INTERNAL (with the traceback on the server's stderr) for bugs.
"""

from __future__ import annotations

import sys
import traceback

import grpc

from graphsvc.errors import GraphsvcError, SearchCancelled, StrategyNotImplementedError
from graphsvc.service.live_workers import WorkerLost


class RpcStatus(Exception):
    """End the call with this status. Raised instead of calling context.abort inside
    handlers, so one place (abort_for) turns every failure into exactly one status."""

    def __init__(self, code: grpc.StatusCode, message: str):
        super().__init__(message)
        self.code = code
        self.message = message


MAX_DETAILS_BYTES = 2048  # a status message rides in a trailer gRPC caps at 16 KiB, percent-encoded


def status_details(text: str) -> str:
    """`text` cut to MAX_DETAILS_BYTES of UTF-8 (an echoed oversize value must not
    turn the answer into RESOURCE_EXHAUSTED)."""
    data = text.encode("utf-8")
    if len(data) <= MAX_DETAILS_BYTES:
        return text
    return data[: MAX_DETAILS_BYTES - 3].decode("utf-8", "ignore") + "…"


def abort_for(context: grpc.ServicerContext, exc: BaseException) -> None:
    """Map an exception to a status and end the call (context.abort raises)."""
    if isinstance(exc, RpcStatus):
        context.abort(exc.code, status_details(exc.message))
    if isinstance(exc, StrategyNotImplementedError):
        context.abort(grpc.StatusCode.UNIMPLEMENTED, status_details(str(exc)))
    if isinstance(exc, WorkerLost):  # the session's state is gone; a new stream would work
        context.abort(grpc.StatusCode.UNAVAILABLE, status_details(str(exc)))
    if isinstance(exc, SearchCancelled):  # the client is gone or out of time; nobody reads this
        context.abort(grpc.StatusCode.CANCELLED, str(exc))
    if isinstance(exc, GraphsvcError):
        context.abort(grpc.StatusCode.INVALID_ARGUMENT, status_details(str(exc)))
    # A bug: keep the traceback for the operator, tell the client only what failed.
    traceback.print_exception(exc, file=sys.stderr)
    context.abort(grpc.StatusCode.INTERNAL, f"internal error ({type(exc).__name__}); see the server log")
