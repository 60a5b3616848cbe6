"""The job store: one SQLite file in the batch folder, one row an item.

A row holds the item's state (queued, running, done, failed), its attempts, the last
error's one-line reason, when its last attempt started and ended, the output's path
and SHA-256, the fingerprint of its inputs and options (`manifest.plan_item`) and the
figures the worker returned. Only the client that drives the batch writes it (workers
write the outputs, the client records them), under the folder's lock, so a second
client on the same folder is refused rather than racing the first. A reader (the
service's GetBatch, `status`) may open it at any time.

Re-running: a done item whose fingerprint is unchanged and whose output still has the
recorded checksum is skipped; every other item is queued again (a running one was
cut off when its client or worker died). Attempts count every dispatch of the same
fingerprint, across runs; a changed fingerprint starts them from 0.
"""

from __future__ import annotations

import contextlib
import json
import os
import sqlite3
import time
from pathlib import Path

from graphsvc.errors import InputError

DB_NAME = "batch.sqlite"
LOCK_NAME = ".batch.lock"
STATES = ("queued", "running", "done", "failed")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS items (
    output TEXT PRIMARY KEY, line INTEGER, fingerprint TEXT, state TEXT, attempts INTEGER,
    reason TEXT, started REAL, ended REAL, output_path TEXT, checksum TEXT, result TEXT, position INTEGER
);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT);
"""


def open_store(folder) -> sqlite3.Connection:
    """The store of a batch folder (created if absent)."""
    con = sqlite3.connect(Path(folder) / DB_NAME, timeout=30.0, isolation_level=None)
    con.row_factory = sqlite3.Row
    con.executescript(_SCHEMA)
    return con


def open_existing(folder) -> sqlite3.Connection:
    """A batch folder's store, read-only use; InputError if the folder holds none."""
    path = Path(folder) / DB_NAME
    if not path.is_file():
        raise InputError(f"{folder} holds no batch (no {DB_NAME})")
    return open_store(folder)


@contextlib.contextmanager
def folder_lock(folder):
    """Hold the batch folder's lock: InputError if another client holds it."""
    import fcntl

    fd = os.open(Path(folder) / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(f"another batch is running in {folder} (it holds {LOCK_NAME})") from None
        yield
    finally:
        os.close(fd)


def set_meta(con, key: str, value) -> None:
    con.execute("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, json.dumps(value)))


def get_meta(con, key: str, default=None):
    row = con.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
    return default if row is None else json.loads(row["value"])


def sync(con, plans, output_checksum) -> list:
    """Enter the planned items; return those to run (manifest order). A done row with
    the same fingerprint whose output still has its checksum (output_checksum(path):
    the file's SHA-256, or None when it is gone) is kept; any other row is queued,
    its attempts kept for the same fingerprint and reset for a changed one."""
    todo = []
    with _transaction(con):
        for position, plan in enumerate(plans):
            row = con.execute("SELECT * FROM items WHERE output = ?", (plan.item.output,)).fetchone()
            same = row is not None and row["fingerprint"] == plan.fingerprint
            if (
                same
                and row["state"] == "done"
                and row["output_path"]
                and output_checksum(row["output_path"]) == row["checksum"]
            ):
                con.execute(
                    "UPDATE items SET line = ?, position = ? WHERE output = ?",
                    (plan.item.line, position, plan.item.output),
                )
                continue
            con.execute(
                "INSERT OR REPLACE INTO items VALUES (?, ?, ?, 'queued', ?, ?, NULL, NULL, NULL, NULL, NULL, ?)",
                (
                    plan.item.output,
                    plan.item.line,
                    plan.fingerprint,
                    row["attempts"] if same else 0,
                    row["reason"] if same else None,
                    position,
                ),
            )
            todo.append(plan)
    return todo


def mark_running(con, output: str) -> int:
    """A new attempt starts; returns its number."""
    with _transaction(con):
        con.execute(
            "UPDATE items SET state = 'running', attempts = attempts + 1, started = ?, ended = NULL WHERE output = ?",
            (time.time(), output),
        )
        return con.execute("SELECT attempts FROM items WHERE output = ?", (output,)).fetchone()[0]


def mark_done(con, output: str, result: dict) -> None:
    con.execute(
        "UPDATE items SET state = 'done', reason = NULL, ended = ?, output_path = ?, checksum = ?, result = ? "
        "WHERE output = ?",
        (time.time(), result["output"], result["checksum"], json.dumps(result), output),
    )


def mark_failed(con, output: str, reason: str, final: bool = True) -> None:
    """The attempt failed: 'failed' if final, else queued for another."""
    con.execute(
        "UPDATE items SET state = ?, reason = ?, ended = ? WHERE output = ?",
        ("failed" if final else "queued", one_line(reason), time.time(), output),
    )


def mark_queued(con, outputs) -> None:
    """Items handed out but not finished (a cancelled batch): queued again."""
    with _transaction(con):
        for output in outputs:
            con.execute("UPDATE items SET state = 'queued' WHERE output = ? AND state = 'running'", (output,))


def rows(con) -> list[dict]:
    """Every item, in manifest order; `result` parsed."""
    out = []
    for r in con.execute("SELECT * FROM items ORDER BY position, output"):
        d = dict(r)
        d["result"] = json.loads(d["result"]) if d["result"] else None
        out.append(d)
    return out


def counts(con) -> dict:
    c = dict.fromkeys(STATES, 0)
    for r in con.execute("SELECT state, COUNT(*) FROM items GROUP BY state"):
        c[r[0]] = r[1]
    return c


def one_line(text: str, limit: int = 300) -> str:
    line = " ".join(str(text).split())
    return line if len(line) <= limit else line[: limit - 1] + "…"


@contextlib.contextmanager
def _transaction(con):
    con.execute("BEGIN IMMEDIATE")
    try:
        yield
    except BaseException:
        con.execute("ROLLBACK")
        raise
    con.execute("COMMIT")
