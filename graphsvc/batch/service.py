"""Batches submitted to the gRPC service: each one a folder of the server's batch
root (its manifest, outputs, job store and summary), run by `run.run_batch` in a
thread of the server on one Dask client the server opens at its first batch (a local
cluster, or `--batch-scheduler`'s). The status a client polls is read from the job
store, so it survives the server: a batch that was running when the server stopped
reads as `interrupted`, and submitting its manifest again resumes it.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import threading
import time
import uuid
from pathlib import Path

from graphsvc.batch import store
from graphsvc.batch.manifest import read_manifest
from graphsvc.batch.run import check_out_dir, connect, run_batch
from graphsvc.errors import FormatError, GraphsvcError, InputError
from graphsvc.fileio import owner_tag, stale_temporary, write_text_atomic


class BatchNotFound(GraphsvcError):
    """No batch of that id in the batch root."""


class BatchManager:
    """root: the batch root; graphs: {name: path} the manifests may name; scheduler /
    workers: the cluster (`run.connect`); retries: the default."""

    def __init__(self, root, graphs: dict, scheduler: str | None = None, workers: int | None = None):
        self.root = Path(root)
        if not self.root.is_dir():
            raise InputError(f"batch folder {self.root} does not exist")
        check_out_dir(self.root, create=False)
        for tmp in self.root.glob(".*.tmp"):  # batches a killed server was making
            if tmp.is_dir() and stale_temporary(tmp, tmp.name[1:].split(".", 1)[0]):
                shutil.rmtree(tmp, ignore_errors=True)
        self.graphs = dict(graphs)
        self.scheduler, self.workers = scheduler, workers
        self._lock = threading.Lock()
        self._client = self._cluster = None
        self._jobs: dict[str, tuple[threading.Thread, threading.Event]] = {}

    def _dask(self):
        with self._lock:
            if self._client is None:
                self._client, self._cluster = connect(self.scheduler, self.workers)
            return self._client

    def submit(self, text: str, fmt: str = "", retries: int | None = None) -> str:
        """Check the manifest, make the batch's folder and start it; its id.
        FormatError/InputError for a manifest that does not parse."""
        fmt = (fmt or ("json" if text.lstrip()[:1] in ("[", "{") else "csv")).lower()
        if fmt not in ("csv", "json"):
            raise InputError(f"format must be csv or json, got {fmt!r}")
        retries = 2 if retries is None else retries
        if retries < 0:
            raise InputError(f"retries must be ≥ 0, got {retries}")
        batch_id = time.strftime("%Y%m%d-%H%M%S", time.gmtime()) + "-" + uuid.uuid4().hex[:8]
        folder = self.root / batch_id
        # Made whole under a temporary name and renamed into place: a server killed
        # meanwhile leaves no half batch, only a temporary folder its next start removes.
        staging = Path(tempfile.mkdtemp(prefix=f".{batch_id}.{owner_tag()}.", suffix=".tmp", dir=self.root))
        manifest = folder / f"manifest.{fmt}"
        try:
            write_text_atomic(staging / manifest.name, text)
            try:
                items = read_manifest(staging / manifest.name)
            except FormatError as exc:  # (named where the batch would have been)
                raise FormatError(manifest, exc.detail, exc.line) from None
            con = store.open_store(staging)
            try:
                store.set_meta(con, "state", "queued")
                store.set_meta(con, "submitted", time.time())
                store.set_meta(con, "items", len(items))
            finally:
                con.close()
            os.rename(staging, folder)
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            raise
        stop = threading.Event()
        thread = threading.Thread(
            target=self._run, args=(folder, manifest, retries, stop), daemon=True, name=f"graphsvc-batch-{batch_id}"
        )
        with self._lock:
            self._jobs[batch_id] = (thread, stop)
        thread.start()
        return batch_id

    def _run(self, folder: Path, manifest: Path, retries: int, stop: threading.Event) -> None:
        try:
            run_batch(
                manifest,
                folder,
                graphs=self.graphs,
                client=self._dask(),
                retries=retries,
                progress=False,
                should_stop=stop.is_set,
                base=self.root,
            )
        except Exception as exc:  # noqa: BLE001 — the batch's own failure, read by GetBatch
            reason = str(exc) if isinstance(exc, GraphsvcError) else f"internal error ({type(exc).__name__}: {exc})"
            con = store.open_store(folder)
            try:
                store.set_meta(con, "state", "error")
                store.set_meta(con, "error", store.one_line(reason))
            finally:
                con.close()

    def _folder(self, batch_id: str) -> Path:
        folder = self.root / batch_id
        plausible = 0 < len(batch_id) <= 128 and "/" not in batch_id and "\0" not in batch_id
        if not plausible or batch_id.startswith(".") or not (folder / store.DB_NAME).is_file():
            shown = batch_id if len(batch_id) <= 64 else batch_id[:61] + "..."
            raise BatchNotFound(f"batch_id: no batch {shown!r} in this server's batch folder")
        return folder

    def status(self, batch_id: str, items: bool = False) -> dict:
        """{batch_id, state, counts, error, submitted, folder[, items]} from the job store."""
        folder = self._folder(batch_id)
        con = store.open_existing(folder)
        try:
            state = store.get_meta(con, "state", "queued")
            with self._lock:
                job = self._jobs.get(batch_id)
            if state in ("queued", "running") and (job is None or not job[0].is_alive()):
                state = "interrupted"
            counts = store.counts(con)
            total = max(store.get_meta(con, "items", 0), sum(counts.values()))
            counts["queued"] += total - sum(counts.values())  # not yet entered in the store
            out = {
                "batch_id": batch_id,
                "state": state,
                "items": total,
                **counts,
                "error": store.get_meta(con, "error", "") or "",
                "submitted": store.get_meta(con, "submitted", 0.0),
                "folder": str(folder.resolve()),
            }
            if items:
                out["item_rows"] = store.rows(con)
            return out
        finally:
            con.close()

    def list(self) -> list[dict]:
        ids = sorted((p.name for p in self.root.iterdir() if (p / store.DB_NAME).is_file()), reverse=True)
        return [self.status(i) for i in ids]

    def cancel(self, batch_id: str, wait_s: float = 30.0) -> dict:
        """Stop a running batch (its unfinished items queued) and wait for it to stop."""
        self._folder(batch_id)
        with self._lock:
            job = self._jobs.get(batch_id)
        if job is not None:
            job[1].set()
            job[0].join(wait_s)
        return self.status(batch_id)

    def close(self) -> None:
        """Stop every running batch and the cluster."""
        with self._lock:
            jobs = list(self._jobs.values())
        for _, stop in jobs:
            stop.set()
        for thread, _ in jobs:
            thread.join(30.0)
        with self._lock:
            for c in (self._client, self._cluster):
                if c is not None:
                    with contextlib.suppress(Exception):
                        c.close()
            self._client = self._cluster = None
