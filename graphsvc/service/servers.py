"""Several servers behind one client channel: `--server` as a list of addresses or a
name with several DNS records, spread by gRPC's own client-side `round_robin`.

    parse_servers("10.0.0.5:50051,10.0.0.6:50051") → ServerList(target="ipv4:10.0.0.5:50051,10.0.0.6:50051", …)

A live stream is one call, so it stays on the server the balancer picked for it; a new
call goes to the next server that is connected (a server that went away drops out of
the rotation until it answers again). `--server` takes:

- one `HOST:PORT` (as before; a name with several A/AAAA records is spread over them),
- a comma-separated list `HOST:PORT,HOST:PORT,…` (names resolved here, at connect: the
  `ipv4:`/`ipv6:` target syntax of gRPC takes numeric addresses only),
- a gRPC target as is: `ipv4:…`, `ipv6:…`, `dns:…` (`dns:///players.example:50051`),
  `unix:…`.

With several addresses each is probed with a health check first (`probe`): one that
does not answer is named in a warning and the client carries on with the others; none
answering is one line and exit 2 (`NoServerAnswers`, an InputError).
"""

from __future__ import annotations

import ipaddress
import json
import socket
import threading
import time
from dataclasses import dataclass

from graphsvc.errors import InputError

# gRPC's client-side load balancing: every new call goes to the next READY subchannel.
SERVICE_CONFIG = json.dumps({"loadBalancingConfig": [{"round_robin": {}}]})
# The initial metadata of every stream: "HOST pid PID" of the server holding it.
SERVER_METADATA = "graphsvc-server"
SCHEMES = ("ipv4:", "ipv6:", "dns:", "unix:", "unix-abstract:")
PROBE_TIMEOUT_S = 3.0


class NoServerAnswers(InputError):
    """None of the servers --server names answers."""


@dataclass(frozen=True)
class ServerList:
    """target: what the channel connects to; addresses: the servers it names, one
    HOST:PORT each as the user gave it (for probes and warnings); host: the name TLS
    checks the certificate against when the addresses are numeric (the first name given)."""

    target: str
    addresses: tuple[str, ...]
    host: str = ""


def split_host_port(text: str, flag: str = "--server", example: str = "") -> tuple[str, int]:
    """ "HOST:PORT" or "[V6]:PORT" → (host without brackets, port); InputError naming
    `flag` otherwise (with `example`, a valid address, in the message)."""
    value = (text or "").strip()
    host, sep, port = value.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    elif ":" in host:
        raise InputError(f"{flag} {text!r}: an IPv6 address goes in brackets, [ADDRESS]:PORT")
    if not sep or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise InputError(
            f"{flag} {text!r}: expected HOST:PORT with a port 1–65535" + (f" ({example})" if example else "")
        )
    return host, int(port)


def _numeric(host: str, port: int) -> tuple[int, str]:
    """(address family, numeric address) of host, the first IPv4 address when it has one."""
    try:
        ip = ipaddress.ip_address(host)
        return (6 if ip.version == 6 else 4), str(ip)
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError, OSError) as exc:
        raise InputError(f"--server {host}:{port}: cannot resolve {host} ({exc})") from None
    v4 = [i[4][0] for i in infos if i[0] == socket.AF_INET]
    return (4, v4[0]) if v4 else (6, infos[0][4][0])


def parse_servers(text: str) -> ServerList:
    """What `--server` names (see the module docstring); InputError for a malformed one."""
    text = (text or "").strip()
    if not text:
        raise InputError("--server: empty address")
    if text.startswith(SCHEMES):
        scheme, _, rest = text.partition(":")
        if scheme in ("ipv4", "ipv6"):
            addresses = tuple(a.strip() for a in rest.split(",") if a.strip())
            for a in addresses:
                split_host_port(a)
            return ServerList(text, addresses)
        return ServerList(text, (text,))
    parts = [p.strip() for p in text.split(",")]
    if any(not p for p in parts):
        raise InputError(f"--server {text!r}: an empty address in the list")
    hosts = [split_host_port(p) for p in parts]
    if len(parts) == 1:
        return ServerList(parts[0], (parts[0],))
    numeric = [_numeric(h, port) for h, port in hosts]
    names = [h for h, _ in hosts if not _is_ip(h)]
    if all(f == 4 for f, _ in numeric):
        target = "ipv4:" + ",".join(f"{a}:{port}" for (_, a), (_, port) in zip(numeric, hosts))
    else:  # (an IPv4 address in an ipv6: list: its IPv4-mapped form)
        v6 = [a if f == 6 else f"::ffff:{a}" for f, a in numeric]
        target = "ipv6:" + ",".join(f"[{a}]:{port}" for a, (_, port) in zip(v6, hosts))
    return ServerList(target, tuple(parts), names[0] if names else "")


def _is_ip(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
        return True
    except ValueError:
        return False


def probe(address: str, credentials=None, options=(), timeout_s: float = PROBE_TIMEOUT_S) -> tuple[float, str | None]:
    """(seconds it took, None) when a gRPC server answers a health check at `address`
    (whatever its status: a server still loading its graphs answers NOT_SERVING, and
    takes calls a moment later), else (seconds, why not: "UNAVAILABLE: …",
    "DEADLINE_EXCEEDED: …")."""
    import grpc
    from grpc_health.v1 import health_pb2, health_pb2_grpc

    start = time.monotonic()
    channel = (
        grpc.secure_channel(address, credentials, options=list(options))
        if credentials is not None
        else grpc.insecure_channel(address, options=list(options))
    )
    try:
        health_pb2_grpc.HealthStub(channel).Check(health_pb2.HealthCheckRequest(), timeout=timeout_s)
    except grpc.RpcError as exc:
        if exc.code() in (grpc.StatusCode.UNAVAILABLE, grpc.StatusCode.DEADLINE_EXCEEDED):
            return time.monotonic() - start, f"{exc.code().name}: {(exc.details() or '').strip() or 'no answer'}"
        # (it answered: UNIMPLEMENTED, a gRPC server without health checking)
    finally:
        channel.close()
    return time.monotonic() - start, None


def probe_all(
    servers: ServerList, credentials=None, options=(), warn=print, timeout_s: float = PROBE_TIMEOUT_S
) -> float:
    """Probe every address at once; warn(line) for each that does not answer; the
    longest time one that answered took (connecting and answering), seconds.
    NoServerAnswers when none does."""
    answers: dict[str, tuple] = {}

    def one(address: str) -> None:
        answers[address] = probe(address, credentials, options, timeout_s)

    threads = [threading.Thread(target=one, args=(a,), daemon=True) for a in servers.addresses]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    answering = [a for a in servers.addresses if answers[a][1] is None]
    if not answering:
        raise NoServerAnswers("no server answers: " + "; ".join(f"{a} ({answers[a][1]})" for a in servers.addresses))
    for a in servers.addresses:
        if answers[a][1] is not None:
            warn(f"warning: server {a} does not answer ({answers[a][1]}); carrying on with {', '.join(answering)}")
    return max(answers[a][0] for a in answering)
