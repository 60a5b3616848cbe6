"""The server's interceptors, which decide whether a call reaches the servicer:
`CallGate` (which calls the server takes while it loads its graphs, serves and drains
after SIGTERM, and the calls under way) and `BearerTokenInterceptor` (bearer-token
authentication, with the tokens `read_tokens` reads from a token file). Health checks
pass both: probes carry no token, and health answers from the moment the port is
bound to the moment the server stops.
"""

from __future__ import annotations

import hmac
import threading

import grpc

from graphsvc.errors import InputError
from graphsvc.fileio import read_input_text

HEALTH_METHOD_PREFIX = "/grpc.health.v1.Health/"  # open without a token: load balancers and probes


# ---------------------------------------------------------------- authentication


def read_tokens(path) -> tuple[str, ...]:
    """Accepted tokens: one per line; blank lines and lines starting with # are
    skipped. Several lines let a token be rotated without downtime."""
    lines = read_input_text(path, "token file").splitlines()
    tokens = tuple(t.strip() for t in lines if t.strip() and not t.strip().startswith("#"))
    if not tokens:
        raise InputError(f"{path}: no token in the token file")
    return tokens


class BearerTokenInterceptor(grpc.ServerInterceptor):
    """UNAUTHENTICATED unless the call carries `authorization: Bearer <token>` with
    one of `tokens`. Health checks stay open (probes carry no secrets)."""

    def __init__(self, tokens: tuple[str, ...], open_prefixes: tuple[str, ...] = (HEALTH_METHOD_PREFIX,)):
        self._tokens = tuple(t.encode("utf-8") for t in tokens)
        self._open = open_prefixes

    def _authorized(self, metadata) -> bool:
        for key, value in metadata or ():
            if key != "authorization" or not isinstance(value, str):
                continue
            scheme, _, token = value.partition(" ")
            if scheme.lower() != "bearer":
                continue
            given = token.strip().encode("utf-8")
            # Compare against every token in constant time: no early exit that
            # would tell an attacker how much of a guess was right.
            ok = False
            for t in self._tokens:
                ok |= hmac.compare_digest(given, t)
            return ok
        return False

    def intercept_service(self, continuation, handler_call_details):
        if handler_call_details.method.startswith(self._open) or self._authorized(
            handler_call_details.invocation_metadata
        ):
            return continuation(handler_call_details)
        handler = continuation(handler_call_details)
        if handler is None:  # unknown method: gRPC answers UNIMPLEMENTED itself
            return None
        return _answer(
            handler,
            grpc.StatusCode.UNAUTHENTICATED,
            "missing or invalid bearer token (metadata 'authorization: Bearer <token>')",
        )


def _answer(handler: grpc.RpcMethodHandler, code: grpc.StatusCode, message: str) -> grpc.RpcMethodHandler:
    """A handler of the same shape as `handler` that ends the call with `code`."""

    def abort(request_or_iterator, context):
        context.abort(code, message)

    if handler.request_streaming and handler.response_streaming:
        return grpc.stream_stream_rpc_method_handler(abort)
    if handler.request_streaming:
        return grpc.stream_unary_rpc_method_handler(abort)
    if handler.response_streaming:
        return grpc.unary_stream_rpc_method_handler(abort)
    return grpc.unary_unary_rpc_method_handler(abort)


# ---------------------------------------------------------------- the server's stage


class CallGate(grpc.ServerInterceptor):
    """Which calls the server takes, by its stage: while the graphs load (`loading`)
    and while it drains after SIGTERM (`draining`) every call but a health check is
    answered UNAVAILABLE, so health stays open from the moment the port is bound to
    the moment the server stops; while `serving` every call goes through, and the
    calls under way are counted until each ends (gRPC's termination callback, after
    its status went out), so a drain can wait for exactly those."""

    LOADING, SERVING, DRAINING = "loading", "serving", "draining"
    REFUSALS = {
        LOADING: "the server is loading its graphs (health answers NOT_SERVING until it serves); try again",
        DRAINING: "the server is shutting down",
    }

    def __init__(self, open_prefixes: tuple[str, ...] = (HEALTH_METHOD_PREFIX,)):
        self._open = open_prefixes
        self._stage = self.LOADING
        self._active = 0
        self._changed = threading.Condition()

    @property
    def stage(self) -> str:
        return self._stage

    @property
    def active(self) -> int:
        """Calls under way (health checks not counted)."""
        return self._active

    def open(self) -> None:
        with self._changed:
            self._stage = self.SERVING

    def drain(self) -> None:
        with self._changed:
            self._stage = self.DRAINING

    def wait_idle(self, timeout_s: float) -> bool:
        """Wait until no counted call is under way, at most timeout_s; whether none is."""
        with self._changed:
            return self._changed.wait_for(lambda: self._active == 0, timeout=max(0.0, timeout_s))

    def _enter(self) -> str | None:
        """Count a call that starts now; the refusal's message when the server takes none."""
        with self._changed:
            if self._stage != self.SERVING:
                return self.REFUSALS[self._stage]
            self._active += 1
            return None

    def _leave(self) -> None:
        with self._changed:
            self._active -= 1
            self._changed.notify_all()

    def intercept_service(self, continuation, handler_call_details):
        handler = continuation(handler_call_details)
        if handler is None or handler_call_details.method.startswith(self._open):
            return handler  # (None: unknown method, gRPC answers UNIMPLEMENTED itself)
        if self._stage != self.SERVING:
            return _answer(handler, grpc.StatusCode.UNAVAILABLE, self.REFUSALS[self._stage])
        kind = (
            ("stream" if handler.request_streaming else "unary")
            + "_"
            + ("stream" if handler.response_streaming else "unary")
        )
        return handler._replace(**{kind: self._counted(getattr(handler, kind))})

    def _counted(self, behavior):
        def run(request_or_iterator, context):
            # (checked again here: the drain may have begun since the call arrived)
            refusal = self._enter()
            if refusal is not None:
                context.abort(grpc.StatusCode.UNAVAILABLE, refusal)
            if not context.add_callback(self._leave):  # (False: the call has ended already)
                self._leave()
            return behavior(request_or_iterator, context)

        return run
