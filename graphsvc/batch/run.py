"""A batch on Dask: read the manifest, plan and fingerprint its items, sync them with
the job store, hand the ones to run to a cluster (a LocalCluster of one worker a
core, or an existing scheduler's), record each result as it comes back, retry what
failed for reasons other than its input, and write the summary.

Everything a user can get wrong — the manifest, the output folder, the scheduler's
address — is checked before anything is written (GraphsvcError: the CLI prints one
line and exits 2). A worker that dies mid-item costs that attempt: the local
cluster's scheduler is told to give up on a task at its first worker death
(`allowed_failures=0`) so the client sees it, records the attempt and resubmits it.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import time
import uuid
from pathlib import Path

from graphsvc.batch import store
from graphsvc.batch.manifest import plan_item, read_manifest
from graphsvc.batch.work import run_item
from graphsvc.errors import InputError
from graphsvc.fileio import file_sha256, require_file, write_text_atomic
from graphsvc.motion.output import MOTION_OUTPUT_SUFFIXES

CONNECT_TIMEOUT_S = 10.0
# The workers' numeric libraries single-threaded: the workers are the parallelism.
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}


def version() -> str:
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as v

    try:
        return v("graphsvc")
    except PackageNotFoundError:
        return "unknown"


def check_out_dir(out_dir, create: bool = True) -> Path:
    """The batch folder (made if absent and `create`); InputError if it, or the folder
    it would be made in, cannot be written."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"output folder {out} is a file")
    probe = out if out.is_dir() else out.parent
    try:
        with tempfile.NamedTemporaryFile(dir=probe, prefix=".write-test."):
            pass
        if create:
            out.mkdir(exist_ok=True)
    except OSError as exc:
        raise InputError(f"output folder {out} is not writable ({exc.strerror or exc})") from None
    return out.resolve()


def local_cluster(workers: int | None = None):
    """A LocalCluster of `workers` single-threaded worker processes (default: one a
    core), no dashboard; its scheduler fails a task at its first worker death."""
    import logging

    from distributed import LocalCluster  # (lazy: dask only where a batch runs)

    n = workers or os.cpu_count() or 1
    if n < 1:
        raise InputError(f"--workers must be ≥ 1, got {n}")
    with kept_environ():
        return LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
            scheduler_kwargs={"allowed_failures": 0},
            env=WORKER_ENV,
        )


@contextlib.contextmanager
def kept_environ():
    """Undo what a Dask nanny writes into this process's environment to hand to the
    worker it spawns (thread counts, PYTHONHASHSEED): processes this one starts later
    must not inherit them."""
    saved = dict(os.environ)
    try:
        yield
    finally:
        for key in set(os.environ) - set(saved):
            del os.environ[key]
        os.environ.update(saved)


def connect(scheduler: str | None, workers: int | None, timeout_s: float = CONNECT_TIMEOUT_S):
    """(client, cluster or None): a client of `scheduler` (else $DASK_SCHEDULER_ADDRESS),
    or of a new local cluster. InputError, one line, when the scheduler does not
    answer within timeout_s."""
    from distributed import Client

    address = scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS")
    if address:
        if workers is not None:
            raise InputError("--workers starts a local cluster: not with --scheduler (the cluster has its own workers)")
        try:
            return Client(address, timeout=f"{timeout_s}s", set_as_default=False), None
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(
                f"scheduler {address} did not answer within {timeout_s:g} s "
                f"({type(exc).__name__}: {store.one_line(exc, 120) or 'no reply'})"
            ) from None
    if workers is not None and workers < 1:
        raise InputError(f"--workers must be ≥ 1, got {workers}")
    cluster = local_cluster(workers)
    return Client(cluster, set_as_default=False), cluster


def cluster_map(client):
    """A `graph.build.ClipMap` on a Dask client: each item a task (scattered to the
    workers first: clips are megabytes, too big to ride in the task graph), results
    gathered in the items' order; a progress bar as they finish."""
    from distributed import as_completed

    def run(fn, items, desc: str = "", progress: bool | None = None) -> list:
        if not items:
            return []
        from tqdm import tqdm

        futures = client.map(fn, client.scatter(list(items)), pure=False)
        with tqdm(
            total=len(futures), desc=desc, unit="clip", disable=None if progress is None else not progress
        ) as bar:
            for _ in as_completed(futures, loop=client.loop):
                bar.update(1)
        return client.gather(futures)

    return run


def run_batch(
    manifest,
    out_dir,
    graphs: dict | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    retries: int = 2,
    progress: bool | None = None,
    should_stop=None,
    client=None,
    timeout_s: float = CONNECT_TIMEOUT_S,
    on_item=None,
    base=None,
) -> dict:
    """Run a manifest's items into `out_dir` and return the summary (also written to
    out_dir/summary.json). graphs: {name: path} for the manifest's graph names;
    retries: further attempts an item gets after a failure that is not its input's;
    progress: the bar (None: when stderr is a terminal); should_stop: polled, the
    batch stops (its unfinished items queued) when it returns true; client: a
    distributed Client to use instead of connecting; on_item(output, state): called
    as items finish; base: the folder relative paths are taken from (default: the
    manifest's)."""
    if retries < 0:
        raise InputError(f"--retries must be ≥ 0, got {retries}")
    manifest = Path(manifest)
    items = read_manifest(manifest)
    for name, path in (graphs or {}).items():
        require_file(path, f"graph {name}")
    check_out_dir(out_dir, create=False)
    own = None
    if client is None:
        client, cluster = connect(scheduler, workers, timeout_s)
        own = (client, cluster)
    try:
        out = check_out_dir(out_dir)
        with store.folder_lock(out), kept_environ():  # (a worker restarted by its nanny)
            return _run(
                client,
                manifest,
                items,
                out,
                graphs or {},
                retries,
                progress,
                should_stop,
                on_item,
                Path(base) if base is not None else manifest.parent,
            )
    finally:
        if own is not None:
            with contextlib.suppress(Exception):
                own[0].close()
            if own[1] is not None:
                with contextlib.suppress(Exception):
                    own[1].close()


def _run(client, manifest: Path, items, out: Path, graphs, retries, progress, should_stop, on_item, base: Path) -> dict:
    t0 = time.perf_counter()
    ver = version()
    plans = [plan_item(item, base, graphs, out, ver) for item in items]
    _remove_temporaries(out, [p.item.output for p in plans])
    con = store.open_store(out)
    try:
        store.set_meta(con, "manifest", str(manifest.resolve()))
        store.set_meta(con, "started", time.time())
        store.set_meta(con, "state", "running")
        todo = store.sync(con, plans, lambda path: file_sha256(path) if Path(path).is_file() else None)
        skipped = len(plans) - len(todo)
        bar = _Progress(len(plans), skipped, progress)
        pending = {}  # future → plan
        failures: dict[str, int] = {}  # this run's failed attempts of an item
        order = {p.item.output: k for k, p in enumerate(plans)}

        def submit(plan):
            store.mark_running(con, plan.item.output)
            key = f"graphsvc-batch-{plan.item.output}-{uuid.uuid4().hex[:12]}"
            f = client.submit(run_item, plan.task, key=key, pure=False, priority=-order[plan.item.output])
            pending[f] = plan

        for plan in todo:
            if plan.error is not None:
                store.mark_running(con, plan.item.output)
                store.mark_failed(con, plan.item.output, plan.error)
                bar.update(None, failed=True)
                if on_item:
                    on_item(plan.item.output, "failed")
            else:
                submit(plan)
        stopped = False
        while pending:
            if should_stop is not None and should_stop():
                stopped = True
                break
            done = [f for f in pending if f.done()]
            if not done:
                time.sleep(0.02)
                continue
            for f in done:
                plan = pending.pop(f)
                name = plan.item.output
                try:
                    result = f.result()
                except Exception as exc:  # a worker died, or a bug: retried while this run's attempts last
                    failures[name] = failures.get(name, 0) + 1
                    reason = _reason(exc)
                    final = failures[name] > retries
                    store.mark_failed(con, name, reason, final=final)
                    if not final:
                        submit(plan)
                        continue
                    result = {"error": reason}
                f.release()
                if "error" in result:
                    store.mark_failed(con, name, result["error"])
                else:
                    store.mark_done(con, name, result)
                bar.update(result, failed="error" in result)
                if on_item:
                    on_item(name, "failed" if "error" in result else "done")
        if stopped:
            for f in pending:
                f.cancel()
            store.mark_queued(con, [p.item.output for p in pending.values()])
        bar.close()
        _remove_temporaries(out, [p.item.output for p in plans])
        state = "cancelled" if stopped else "finished"
        store.set_meta(con, "state", state)
        summary = make_summary(con, [p.item.output for p in plans], time.perf_counter() - t0, skipped, state)
        write_text_atomic(out / "summary.json", json.dumps(summary, indent=1, sort_keys=True) + "\n")
        return summary
    finally:
        con.close()


def _reason(exc: BaseException) -> str:
    from distributed import KilledWorker

    if isinstance(exc, KilledWorker):
        return "its worker died during the item"
    return store.one_line(f"{type(exc).__name__}: {exc}")


def _remove_temporaries(out: Path, outputs) -> None:
    """Temporary files a killed worker left beside its outputs (fileio.atomic_writer's)."""
    for name in outputs:
        for suffix in (*MOTION_OUTPUT_SUFFIXES, ".json"):
            for tmp in out.glob(f".{name}{suffix}.*.tmp"):
                with contextlib.suppress(OSError):
                    tmp.unlink()


def make_summary(con, outputs, seconds: float, skipped: int, state: str) -> dict:
    """Per item (state, attempts, seconds, samples/s, the output's jitter and foot skate,
    per-term costs or the reason), the totals, the failures."""
    by_name = {r["output"]: r for r in store.rows(con)}
    items, failures = [], []
    total_samples = total_input = total_item_s = 0.0
    for name in outputs:
        r = by_name[name]
        res = r["result"] or {}
        entry = {"output": name, "line": r["line"], "state": r["state"], "attempts": r["attempts"]}
        if r["state"] == "done":
            entry.update(
                seconds=round(res["seconds"], 4),
                samples=res["samples"],
                input_s=round(res["input_s"], 3),
                samples_per_s=res.get("samples_per_s"),
                cost=res.get("cost"),
                terms=res.get("terms", {}),
                path=r["output_path"],
                checksum=r["checksum"],
                **{k: res[k] for k in ("jitter_km_s3", "skate_cm_s") if k in res},
            )
            total_samples += res["samples"]
            total_input += res["input_s"]
            total_item_s += res["seconds"]
        elif r["reason"]:
            entry["reason"] = r["reason"]
            if r["state"] == "failed":
                failures.append({"output": name, "line": r["line"], "reason": r["reason"]})
        items.append(entry)
    c = {s: sum(1 for e in items if e["state"] == s) for s in store.STATES}
    return {
        "state": state,
        "items": items,
        "totals": {
            "items": len(items),
            **c,
            "skipped": skipped,
            "seconds": round(seconds, 3),
            "samples": int(total_samples),
            "input_hours": round(total_input / 3600.0, 5),
            "item_seconds": round(total_item_s, 3),
            "items_per_s": round((len(items) - skipped) / seconds, 4) if seconds > 0 else None,
            "input_hours_per_s": round(total_input / 3600.0 / seconds, 6) if seconds > 0 else None,
        },
        "failures": failures,
    }


def format_summary(summary: dict) -> str:
    """The summary as a table: per item seconds, samples/s, what a viewer sees (jitter,
    foot skate), cost and its terms; totals; failures."""
    terms = sorted({t for e in summary["items"] for t in e.get("terms", {})})
    head = ["output", "state", "tries", "s", "samples/s", "jitter km/s³", "skate cm/s", "cost", *terms]
    lines = [head]
    for e in summary["items"]:
        if e["state"] == "done":
            lines.append(
                [
                    e["output"],
                    e["state"],
                    str(e["attempts"]),
                    f"{e['seconds']:.2f}",
                    f"{e['samples_per_s']:,.0f}" if e.get("samples_per_s") else "-",
                    f"{e['jitter_km_s3']:.2f}" if e.get("jitter_km_s3") is not None else "-",
                    f"{e['skate_cm_s']:.1f}" if e.get("skate_cm_s") is not None else "-",
                    f"{e['cost']:.2f}" if e.get("cost") is not None else "-",
                    *(f"{e['terms'][t]:.2f}" if t in e.get("terms", {}) else "-" for t in terms),
                ]
            )
        else:
            lines.append([e["output"], e["state"], str(e["attempts"])] + ["-"] * (len(head) - 3))
    widths = [max(len(row[k]) for row in lines) for k in range(len(head))]
    text = ["  ".join(v.ljust(w) for v, w in zip(row, widths)).rstrip() for row in lines]
    t = summary["totals"]
    text.append(
        f"total: {t['items']} items, {t['done']} done ({t['skipped']} unchanged, skipped), {t['failed']} failed, "
        f"{t['queued'] + t['running']} not run; {t['input_hours'] * 60:.1f} min of input in {t['seconds']:.1f} s"
    )
    for f in summary["failures"]:
        text.append(f"failed: {f['output']} (line {f['line']}): {f['reason']}")
    return "\n".join(text)


class _Progress:
    """A bar of items with items/s, input hours/s and the ETA (tqdm's)."""

    def __init__(self, total: int, skipped: int, show: bool | None):
        from tqdm import tqdm

        self.t0 = time.perf_counter()
        self.input_s = 0.0
        self.bar = tqdm(
            total=total,
            initial=skipped,
            unit="item",
            disable=False if show else (None if show is None else True),
            desc="batch",
            dynamic_ncols=True,
            smoothing=0.1,
        )

    def update(self, result, failed: bool = False) -> None:
        if result and not failed:
            self.input_s += result.get("input_s", 0.0)
        dt = max(time.perf_counter() - self.t0, 1e-9)
        self.bar.set_postfix_str(f"{self.input_s / 3600.0 / dt:.4f} input-h/s", refresh=False)  # (items/s, ETA: tqdm's)
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()
