"""Live sessions in worker processes, behind the gRPC front.

Why: a live sample costs about 1 ms of CPU in its session (the beam step about 0.6 of
it, in numba without the GIL; the streaming synthesis and the rest in Python): one
process pushing 12 sessions' samples in turn spends 1.03–1.09 ms a sample on the
263k-node Bandai graph. With every stream's push on its own gRPC thread in one
process the threads queue for the one GIL: that server stopped at 1.23 of 2 cores,
24 streams falling seconds behind. So the server keeps gRPC, the checking of each
message and the encoding of the frames in its own process, and runs the sessions in
`count` worker processes, where one thread pushes the sessions' samples one after
another (a stream keeps its worker for life; a new stream goes to the worker with
fewest). The graphs are memory-mapped, so their pages are shared by every process,
and so are the strategies' indexes and tables, mapped from their cache files beside
each graph (`strategies.index`). A worker maps a graph without hashing it again: it
reports the checksum the file's trailer records, and the front, which verified the
file's bytes, refuses a worker whose graph is not the one it verified (the file
replaced meanwhile). A session's start is heavy (40–
160 ms in one push), so its first YOUNG_S seconds of samples, its opening and its
flush run on a second thread of the worker, beside the other sessions' pushes rather
than ahead of them. Measured on 2 cores shared with the clients: 24 streams started
over 20 s at p99 28–37 ms (before the second thread 238 ms; in one process 16 streams
already fell seconds behind; tools/bench_service.py, BENCHMARKS.md).
multiprocessing's pipes carry the messages: a round trip with a worker that only echoes
costs the front about 0.1 ms of CPU, a tenth of a push.

On a worker's pipe (a multiprocessing Connection; pickled tuples):
    front → worker   (op, sid, payload): op "open" (graph name, Options, sensor names,
                     marker names, orientations) → the session's lag_frames; "push"
                     (threads, the sample's arguments) → frames; "flush" (threads) →
                     frames; "close" (no answer); "stop" ends the worker.
    worker → front   (sid, status, value): status "ok"; "input" (an InputError's
                     message and the option or field it names, `options.on_field`:
                     the client's input); "error" (any other failure: its traceback,
                     a defect).
A worker that dies (killed, out of memory) ends each stream it held with `WorkerLost`
(the service answers UNAVAILABLE: the session's state is gone; a new stream starts
afresh) and is replaced in the background; new streams go to the workers alive.
"""

from __future__ import annotations

import itertools
import multiprocessing as mp
import os
import queue
import sys
import threading
import time
import traceback
from pathlib import Path

from graphsvc.errors import GraphsvcError, InputError
from graphsvc.graph.file import load_graph
from graphsvc.pipeline import open_session, warm_up

READY_TIMEOUT_S = 600.0  # loading and warming every graph in a worker (a fresh install compiles)
# A session's first seconds of samples: the heavy pushes of its start (a Viterbi
# search starts after its first second, with most nodes live) run beside the other
# sessions' pushes instead of ahead of them.
YOUNG_S = 2.0


class WorkerLost(GraphsvcError):
    """The worker process holding a live session stopped; the session is gone."""


class LiveWorkerError(RuntimeError):
    """A defect in a worker (not the client's input): its traceback, for the log."""


def default_count() -> int:
    """One worker per core this process may run on; none (sessions in the server's
    own process) on a single core, where a worker only adds the pipe's cost."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return cores if cores > 1 else 0


# ---------------------------------------------------------------- the worker process


def _worker_main(conn, graph_paths: dict[str, str]) -> None:
    """A worker: load and warm every graph, say "ready", then answer requests until
    "stop" or the front's end of the pipe closes. Each session's requests come one at
    a time (the front waits for each answer), so either thread may take them: a
    session's opening, its first YOUNG_S seconds of samples and its flush run on the
    side thread, everything else on this one."""
    try:
        graphs = {}
        for name, path in graph_paths.items():
            graphs[name] = load_graph(Path(path), verify=False)  # (the front verifies the bytes)
            warm_up(graphs[name], threads=False)
            warm_up(graphs[name], threads=True)
    except BaseException as exc:  # noqa: BLE001 — told to the front, which refuses to start
        conn.send((None, "error", f"{type(exc).__name__}: {exc}"))
        return
    conn.send((None, "ok", (os.getpid(), {name: g.checksum for name, g in graphs.items()})))

    sessions: dict = {}
    young: dict[int, int] = {}  # session → pushes still to go to the side thread
    send_lock = threading.Lock()
    side: queue.SimpleQueue = queue.SimpleQueue()

    def answer(op, sid, payload) -> bool:
        reply = _answer(graphs, sessions, op, sid, payload)
        try:
            with send_lock:
                conn.send(reply)
        except (EOFError, OSError):
            return False  # the front has gone
        return True

    def side_thread():
        while (item := side.get()) is not None and answer(*item):
            pass

    threading.Thread(target=side_thread, name="graphsvc-live-side", daemon=True).start()
    try:
        while True:
            try:
                op, sid, payload = conn.recv()
            except (EOFError, OSError):
                return  # the front has gone
            if op == "stop":
                return
            if op == "close":
                sessions.pop(sid, None)
                young.pop(sid, None)
                continue
            if op == "open" and payload[0] in graphs:
                young[sid] = max(1, round(YOUNG_S * graphs[payload[0]].rate_hz))
            if op in ("open", "flush") or (op == "push" and young.get(sid, 0) > 0):
                if op == "push":
                    young[sid] -= 1
                side.put((op, sid, payload))
            elif not answer(op, sid, payload):
                return
    finally:
        side.put(None)


def _answer(graphs, sessions, op, sid, payload) -> tuple:
    """One request's answer (sid, status, value); see the module docstring."""
    try:
        if op == "open":
            name, options, names, marker_names, orientations = payload
            session = open_session(
                graphs[name], options, names, keep_motion=False, marker_names=marker_names, orientations=orientations
            )
            sessions[sid] = session
            return (sid, "ok", session.lag_frames)
        if op == "push":
            threads, args, kwargs = payload
            session = sessions[sid]
            session.threads = threads
            return (sid, "ok", session.push(*args, **kwargs))
        if op == "flush":
            session = sessions[sid]
            session.threads = payload
            return (sid, "ok", session.flush())
        return (sid, "error", f"unknown request {op!r}")
    except InputError as exc:
        return (sid, "input", (str(exc), getattr(exc, "option_field", None)))
    except Exception:  # noqa: BLE001 — a defect: its traceback goes to the front
        return (sid, "error", traceback.format_exc())


# ---------------------------------------------------------------- the front's side


class _Worker:
    """One worker process as the front sees it: its pipe, a lock for sending, the
    sessions it holds and a thread that hands each answer to its session."""

    def __init__(self, index: int, process, conn, pid: int):
        self.index = index
        self.process = process
        self.conn = conn
        self.pid = pid
        self.send_lock = threading.Lock()
        self.sessions: dict[int, RemoteSession] = {}
        self.sessions_lock = threading.Lock()
        self.alive = True
        self.started_at = time.monotonic()

    def send(self, message) -> None:
        try:
            with self.send_lock:
                self.conn.send(message)
        except (OSError, EOFError, ValueError):  # ValueError: the pipe was closed here
            raise WorkerLost(self.lost_reason()) from None

    def ending(self, wait_s: float = 0.5) -> str:
        """How the process ended: "killed by signal 9", "exit code 1", … A pipe breaks a
        moment before the dying process can be reaped: it is waited for up to wait_s
        ("still running" after that)."""
        if self.process.exitcode is None and wait_s > 0:
            self.process.join(wait_s)
        code = self.process.exitcode
        return "still running" if code is None else (f"killed by signal {-code}" if code < 0 else f"exit code {code}")

    def lost_reason(self) -> str:
        return (
            f"the live worker process {self.pid} holding this stream stopped ({self.ending()}); its session is "
            "gone: start a new stream"
        )


class RemoteSession:
    """A LiveSession run by a worker process: push/flush/close as LiveSession's (set
    `threads` before a push, as on a LiveSession)."""

    def __init__(self, worker: _Worker, sid: int):
        self.worker = worker
        self.sid = sid
        self.threads = False
        self.lag_frames = 0
        self.lost: str | None = None
        self.closed = False
        self._answers: queue.SimpleQueue = queue.SimpleQueue()

    def _call(self, op: str, payload):
        if self.lost is not None:
            raise WorkerLost(self.lost)
        self.worker.send((op, self.sid, payload))
        status, value = self._answers.get()
        if status == "ok":
            return value
        if status == "input":
            message, name = value
            exc = InputError(message)
            if name is not None:
                exc.option_field = name
            raise exc
        if status == "lost":
            raise WorkerLost(value)
        raise LiveWorkerError(f"in live worker {self.worker.pid}:\n{value}")

    def push(self, *args, **kwargs):
        return self._call("push", (bool(self.threads), args, kwargs))

    def flush(self):
        return self._call("flush", bool(self.threads))

    def close(self) -> None:
        """Free the session in its worker (once; nothing if the worker is gone)."""
        if self.closed:
            return
        self.closed = True
        with self.worker.sessions_lock:
            self.worker.sessions.pop(self.sid, None)
        if self.lost is None:
            try:
                self.worker.send(("close", self.sid, None))
            except WorkerLost:
                pass


class LiveWorkers:
    """`count` worker processes, each serving every graph in graph_paths (name → file)."""

    def __init__(self, graph_paths: dict[str, Path], count: int, restart_delay_s: float = 10.0):
        """restart_delay_s: a worker that died within this many seconds of starting (or
        whose replacement could not start) is started again only after this long, so
        a worker that cannot run is not restarted in a tight loop."""
        if count < 1:
            raise InputError(f"live workers: at least 1, got {count}")
        self.graph_paths = {name: str(path) for name, path in graph_paths.items()}
        self.count = count
        self._context = mp.get_context("spawn")  # (fork would copy the front's gRPC and numba threads' state)
        self._workers: list[_Worker | None] = [None] * count
        self._pending: list = []  # (process, connection) launched, not yet ready
        self._lock = threading.Lock()
        self._ids = itertools.count(1)
        self._stopping = False
        self.restart_delay_s = float(restart_delay_s)
        self.replaced = 0  # workers that died and were started again
        # name → SHA-256 of each graph as the front verified it (`expect`); a worker
        # that mapped other bytes is refused.
        self.checksums: dict[str, str] = {}

    # ------------------------------------------------------------ lifetime

    def start(self) -> None:
        """Start every worker and wait until each has loaded and warmed its graphs;
        GraphsvcError (the others stopped) if one cannot."""
        self.launch()
        self.wait_ready()

    def launch(self) -> None:
        """Start the worker processes (they load the graphs meanwhile); returns at once."""
        if not self._pending and not any(self._workers):
            self._pending = [self._spawn() for _ in range(self.count)]

    def expect(self, checksums: dict[str, str]) -> None:
        """The graphs' checksums as the front verified them (name → SHA-256 hex): a
        worker ready after this with other bytes mapped is refused."""
        self.checksums = dict(checksums)

    def wait_ready(self) -> None:
        """Wait until every launched worker is ready (`start`)."""
        pending, self._pending = self._pending, []
        try:
            for index, (process, conn) in enumerate(pending):
                self._workers[index] = self._await_ready(index, process, conn)
        except BaseException:
            for process, conn in pending:
                conn.close()
                process.kill()
            raise

    def _spawn(self):
        front, back = self._context.Pipe(duplex=True)
        process = self._context.Process(
            target=_worker_main, args=(back, self.graph_paths), daemon=True, name="graphsvc-live-worker"
        )
        process.start()
        back.close()
        return process, front

    def _await_ready(self, index: int, process, conn) -> _Worker:
        if not conn.poll(READY_TIMEOUT_S):
            raise GraphsvcError(f"live worker {process.pid}: not ready within {READY_TIMEOUT_S:g} s")
        try:
            _, status, value = conn.recv()
        except (EOFError, OSError):
            raise GraphsvcError(
                f"live worker {process.pid} stopped while loading the graphs (exit code {process.exitcode})"
            ) from None
        if status != "ok":
            raise GraphsvcError(f"live worker {process.pid} could not load the graphs: {value}")
        pid, checksums = value
        changed = sorted(n for n, c in self.checksums.items() if checksums.get(n) != c)
        if changed:
            process.kill()
            raise GraphsvcError(
                f"live worker {pid}: the graph file of {', '.join(changed)} is not the one the server verified"
                " (replaced while the server started?)"
            )
        worker = _Worker(index, process, conn, pid)
        threading.Thread(
            target=self._receive, args=(worker,), name=f"graphsvc-live-worker-{index}", daemon=True
        ).start()
        return worker

    def stop(self, timeout_s: float = 5.0) -> None:
        """Ask every worker to stop; kill any still running after timeout_s."""
        with self._lock:
            self._stopping = True
            workers = [w for w in self._workers if w is not None]
            pending, self._pending = self._pending, []
        for process, conn in pending:  # launched, still loading: nothing to lose
            process.kill()
            process.join(1.0)
            conn.close()
        for worker in workers:
            try:
                worker.send(("stop", 0, None))
            except WorkerLost:
                pass
        end = time.monotonic() + timeout_s
        for worker in workers:
            worker.process.join(max(0.0, end - time.monotonic()))
            if worker.process.is_alive():
                worker.process.kill()
                worker.process.join(1.0)
            worker.conn.close()

    # ------------------------------------------------------------ sessions

    def open(self, graph_name: str, options, names, marker_names=(), orientations: bool = False) -> RemoteSession:
        """A new session on the worker holding fewest; InputError as LiveSession
        raises it; WorkerLost when no worker is alive."""
        with self._lock:
            alive = [w for w in self._workers if w is not None and w.alive]
            if not alive:
                raise WorkerLost("no live worker process is running (they are being started again): retry shortly")
            worker = min(alive, key=lambda w: (len(w.sessions), w.index))
            session = RemoteSession(worker, next(self._ids))
            with worker.sessions_lock:
                worker.sessions[session.sid] = session
        try:
            session.lag_frames = session._call(
                "open", (graph_name, options, tuple(names), tuple(marker_names or ()), bool(orientations))
            )
        except BaseException:
            session.close()
            raise
        return session

    def sessions(self) -> int:
        """Sessions open in all workers."""
        return sum(len(w.sessions) for w in self._workers if w is not None)

    def pids(self) -> list[int]:
        return [w.pid for w in self._workers if w is not None and w.alive]

    def processes(self) -> list[tuple[int, int]]:
        """(slot 0…count−1, pid) of each worker alive."""
        return [(w.index, w.pid) for w in self._workers if w is not None and w.alive]

    # ------------------------------------------------------------ answers and deaths

    def _receive(self, worker: _Worker) -> None:
        """Hand each answer to its session until the pipe ends; then the worker is
        lost: its sessions are told, and (unless stopping) a new worker replaces it."""
        while True:
            try:
                sid, status, value = worker.conn.recv()
            except (EOFError, OSError, ValueError):
                break
            session = worker.sessions.get(sid)
            if session is not None:
                session._answers.put((status, value))
        worker.process.join(1.0)
        reason = worker.lost_reason()
        with self._lock:
            worker.alive = False
            stopping = self._stopping
        with worker.sessions_lock:
            held = list(worker.sessions.values())
        for session in held:
            session.lost = reason
            session._answers.put(("lost", reason))
        if not stopping:
            print(
                f"graphsvc serve: live worker process {worker.pid} stopped ({worker.ending()}); "
                f"{len(held)} stream(s) ended with UNAVAILABLE; starting a new worker",
                file=sys.stderr,
                flush=True,
            )
            threading.Thread(
                target=self._replace, args=(worker,), name="graphsvc-live-worker-restart", daemon=True
            ).start()

    def _replace(self, dead: _Worker) -> None:
        if time.monotonic() - dead.started_at < self.restart_delay_s:
            time.sleep(self.restart_delay_s)
        while True:
            with self._lock:
                if self._stopping:
                    return
            process, conn = self._spawn()
            try:
                worker = self._await_ready(dead.index, process, conn)
            except GraphsvcError as exc:
                print(f"graphsvc serve: {exc}; trying again in {self.restart_delay_s:g} s", file=sys.stderr, flush=True)
                process.kill()
                time.sleep(self.restart_delay_s)
                continue
            with self._lock:
                if self._stopping:
                    worker.send(("stop", 0, None))
                    return
                self._workers[dead.index] = worker
                self.replaced += 1
            return
