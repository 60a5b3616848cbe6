#!/usr/bin/env python3
"""Fuzz one reader for a while and print JSON: executions, outcomes, findings.

    tools/fuzz.py TARGET --seconds N [--corpus DIR] [--out DIR] [--engine auto|atheris|mutate]
    tools/fuzz.py --list

TARGET is a name of graphsvc.fuzz.targets.TARGETS (--list prints them). The engine
is atheris (coverage-guided, libFuzzer) when it is installed, else the built-in
mutation loop (graphsvc.fuzz.run) over the seed corpus and the files of --corpus.
The fuzzing runs in a child process the parent supervises: a child killed by a
signal (a crash in C or C++ code) or silent for longer than the per-input time limit
(a hang in compiled code) is recorded with the input in flight and restarted with
the next seed until the time is up. Memory: the child's address space is bounded
(RLIMIT_AS, --memory-mb beyond what it holds after start-up) and, in the built-in
loop, each input's traced allocation peak (--trace-mb). Every finding's input is
saved in --out (default fuzz-findings/TARGET) as KIND-HASH with KIND-HASH.txt
beside it (error and traceback); replay one with --replay FILE.
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _limit_memory(budget_mb: int) -> None:
    """Bound the address space at what the process maps now plus `budget_mb`."""
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[0])
    limit = pages * resource.getpagesize() + budget_mb * (1 << 20)
    resource.setrlimit(resource.RLIMIT_AS, (limit, resource.getrlimit(resource.RLIMIT_AS)[1]))


def _save(out: Path, data: bytes, kind: str, text: str) -> Path:
    from graphsvc.fuzz.run import input_id

    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{kind}-{input_id(data)}"
    path.write_bytes(data)
    path.with_name(path.name + ".txt").write_text(text)
    return path


def _corpus(target, folder: str | None) -> list[bytes]:
    corpus = list(target.seeds())
    if folder:
        corpus += [p.read_bytes() for p in sorted(Path(folder).iterdir()) if p.is_file() and p.suffix != ".txt"]
    return corpus


# ---------------------------------------------------------------- the child


def _worker_mutate(args, target, state: Path) -> dict:
    from graphsvc.fuzz.run import mutation_loop

    corpus = _corpus(target, args.corpus)
    current, count = state / "current", [0]

    def in_flight(data: bytes) -> None:
        current.write_bytes(data)
        count[0] += 1
        if count[0] % 64 == 0:  # what the parent counts if this child dies
            (state / "count").write_text(str(count[0]))

    def found(data: bytes, outcome) -> None:
        _save(Path(args.out), data, outcome.kind, f"{outcome.error}\n\n{outcome.trace}")

    _limit_memory(args.memory_mb)
    stats = mutation_loop(
        target,
        corpus,
        seed=args.seed,
        seconds=args.seconds,
        time_limit_s=args.time_limit,
        memory_limit=args.trace_mb << 20,
        on_finding=found,
        on_execution=in_flight,
    )
    out = stats.as_dict()
    out["findings"] = [{"kind": o.kind, "error": o.error[:300]} for _, o in stats.findings]
    return out


def _worker_atheris(args, target, state: Path) -> None:
    import atheris

    from graphsvc.fuzz.run import run_one

    corpus_dir = Path(args.corpus) if args.corpus else state / "corpus"
    corpus_dir.mkdir(parents=True, exist_ok=True)
    from graphsvc.fuzz.run import input_id

    for data in target.seeds():
        (corpus_dir / f"seed-{input_id(data)}").write_bytes(data)
    Path(args.out).mkdir(parents=True, exist_ok=True)

    def test_one(data: bytes) -> None:
        outcome = run_one(target, data, time_limit_s=args.time_limit)
        if outcome.finding:
            _save(Path(args.out), data, outcome.kind, f"{outcome.error}\n\n{outcome.trace}")
            raise RuntimeError(f"{outcome.kind}: {outcome.error}")

    argv = [
        sys.argv[0],
        f"-max_total_time={max(1, int(args.seconds))}",
        f"-timeout={int(args.time_limit) + 1}",
        f"-rss_limit_mb={args.memory_mb + 1024}",
        f"-seed={args.seed + 1}",
        "-print_final_stats=1",
        f"-artifact_prefix={args.out}/",
        "-max_len=262144",
        str(corpus_dir),
    ]
    atheris.Setup(argv, test_one)
    atheris.Fuzz()


def worker(args) -> None:
    state = Path(args.worker)
    tempfile.tempdir = str(state)  # the child's scratch files go where the parent removes them, even after a crash
    if args.engine == "atheris":
        import atheris

        # numba compiles a kernel from its bytecode: modules that define kernels stay
        # uninstrumented (their Python code is then not coverage-guided).
        compiled = sorted(
            ".".join(p.relative_to(ROOT).with_suffix("").parts)
            for p in (ROOT / "graphsvc").rglob("*.py")
            if "njit" in (text := p.read_text()) or "numba.jit" in text or "@numba" in text
        )
        with atheris.instrument_imports(include=["graphsvc"], exclude=compiled):
            from graphsvc.fuzz.targets import TARGETS

            target = TARGETS[args.target]
            target.seeds()  # imports (and so instruments) what the target reads with
            for data in target.seeds():
                target.run(data)
        _worker_atheris(args, target, state)
        return
    from graphsvc.fuzz.targets import TARGETS

    target = TARGETS[args.target]
    (state / "stats.json").write_text(json.dumps(_worker_mutate(args, target, state)))


# ---------------------------------------------------------------- the parent


def _atheris_executions(stderr: str) -> int:
    for line in stderr.splitlines()[::-1]:
        if line.startswith("stat::number_of_executed_units:"):
            return int(line.split(":")[-1])
    for line in stderr.splitlines()[::-1]:
        if line.startswith("#") and " " in line:
            head = line[1:].split()[0]
            if head.isdigit():
                return int(head)
    return 0


def supervise(args) -> dict:
    out = Path(args.out)
    deadline = time.monotonic() + args.seconds
    total = {
        "target": args.target,
        "engine": args.engine,
        "seconds": args.seconds,
        "executions": 0,
        "outcomes": {},
        "findings": [],
        "restarts": 0,
    }
    seed = args.seed
    while True:
        left = deadline - time.monotonic()
        if left < 1 and total["restarts"] + total["executions"] > 0:
            break
        state = Path(tempfile.mkdtemp(prefix="graphsvc-fuzz-state-"))
        cmd = [
            sys.executable,
            __file__,
            args.target,
            "--worker",
            str(state),
            "--engine",
            args.engine,
            "--seconds",
            f"{max(left, 1):.1f}",
            "--seed",
            str(seed),
            "--out",
            str(out),
            "--time-limit",
            str(args.time_limit),
            "--memory-mb",
            str(args.memory_mb),
            "--trace-mb",
            str(args.trace_mb),
        ]
        if args.corpus:
            cmd += ["--corpus", args.corpus]
        err = open(state / "stderr", "w+")
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, cwd=ROOT)
        current = state / "current"
        hang = False
        startup = time.monotonic()
        while proc.poll() is None:
            time.sleep(0.2)
            if args.engine == "mutate" and current.exists():
                idle = time.time() - current.stat().st_mtime
                if idle > args.time_limit + 10:  # the child's own alarm did not fire: compiled code hangs
                    hang = True
                    proc.kill()
            if time.monotonic() - startup > left + 120:  # a safety net: never outlive the budget by much
                proc.kill()
        proc.wait()
        err.seek(0)
        stderr = err.read()
        err.close()
        if args.engine == "atheris":
            total["executions"] += _atheris_executions(stderr)
            if proc.returncode != 0:
                crash = [
                    line
                    for line in stderr.splitlines()
                    if "==ERROR" in line or "Uncaught" in line or "deadly signal" in line or "timeout" in line.lower()
                ][:3]
                total["findings"].append({"kind": "atheris", "error": " | ".join(crash)[:300]})
        else:
            stats_file = state / "stats.json"
            if stats_file.exists():
                stats = json.loads(stats_file.read_text())
                total["executions"] += stats["executions"]
                for k, v in stats["outcomes"].items():
                    total["outcomes"][k] = total["outcomes"].get(k, 0) + v
                total["findings"] += stats["findings"]
            elif current.exists():
                count = state / "count"
                total["executions"] += int(count.read_text()) if count.exists() else 1
                data = current.read_bytes()
                kind = "hang" if hang else f"signal-{-proc.returncode}" if proc.returncode < 0 else "exit"
                path = _save(out, data, kind, stderr[-4000:])
                total["findings"].append(
                    {
                        "kind": kind,
                        "error": stderr.strip().splitlines()[-1:] and stderr.strip().splitlines()[-1][:300] or "",
                        "file": str(path),
                    }
                )
        shutil.rmtree(state, ignore_errors=True)
        seed += 1
        total["restarts"] += 1
        if time.monotonic() >= deadline:
            break
    total["restarts"] -= 1
    total["crash_files"] = sorted(p.name for p in out.glob("*") if p.suffix != ".txt") if out.is_dir() else []
    return total


def replay(args) -> dict:
    from graphsvc.fuzz.run import run_one
    from graphsvc.fuzz.targets import TARGETS

    outcome = run_one(TARGETS[args.target], Path(args.replay).read_bytes(), time_limit_s=args.time_limit)
    return {
        "target": args.target,
        "input": args.replay,
        "outcome": outcome.kind,
        "error": outcome.error,
        "trace": outcome.trace,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("target", nargs="?")
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--corpus", help="a folder of extra inputs (atheris also adds what it finds there)")
    p.add_argument("--out", help="where findings are saved (default fuzz-findings/TARGET)")
    p.add_argument("--engine", choices=("auto", "atheris", "mutate"), default="auto")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--time-limit", type=float, default=10.0, help="seconds an input may take")
    p.add_argument("--memory-mb", type=int, default=1024, help="address space beyond the child's after start-up")
    p.add_argument("--trace-mb", type=int, default=512, help="traced allocation peak of one input (built-in loop)")
    p.add_argument("--replay", help="run one saved input and print its outcome")
    p.add_argument("--list", action="store_true")
    p.add_argument("--worker", help=argparse.SUPPRESS)
    args = p.parse_args()
    from graphsvc.fuzz.targets import TARGETS

    if args.list:
        print(json.dumps({name: t.doc for name, t in TARGETS.items()}, indent=1))
        return
    if args.target not in TARGETS:
        print(f"fuzz.py: unknown target {args.target!r} (--list names them)", file=sys.stderr)
        sys.exit(2)
    args.out = args.out or str(ROOT / "fuzz-findings" / args.target)
    if args.engine == "auto":
        try:
            import atheris  # noqa: F401

            args.engine = "atheris"
        except ImportError:
            args.engine = "mutate"
    if args.worker:
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        worker(args)
        return
    result = replay(args) if args.replay else supervise(args)
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
