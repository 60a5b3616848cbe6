"""Running a target on one input and telling the outcome: accepted, refused with one
of the target's allowed errors, or a finding — another exception, a hang (over the
per-input time limit) or a memory blow-up (a MemoryError, or a traced allocation
peak over the bound). And a plain mutation loop over a corpus (`mutation_loop`),
what the test suite runs and what `tools/fuzz.py` runs when atheris is absent."""

from __future__ import annotations

import hashlib
import random
import re
import signal
import threading
import time
import traceback
import tracemalloc
from dataclasses import dataclass, field

from graphsvc.fuzz.mutate import mutate
from graphsvc.fuzz.targets import Target

ACCEPTED, REFUSED, CRASH, HANG, MEMORY = "accepted", "refused", "crash", "hang", "memory"
FINDINGS = (CRASH, HANG, MEMORY)


class Hang(BaseException):
    """Raised by the per-input alarm (a BaseException: no `except Exception` eats it)."""


@dataclass
class Outcome:
    kind: str
    error: str = ""  # exception type and message
    trace: str = ""
    seconds: float = 0.0
    peak_bytes: int = 0

    @property
    def finding(self) -> bool:
        return self.kind in FINDINGS

    def signature(self) -> str:
        """What tells two outcomes apart for the corpus: the kind and the error with
        numbers and quoted text blanked (so every refused frame count is one class)."""
        text = re.sub(r"'[^']*'|\"[^\"]*\"|\d+(\.\d+)?", "#", self.error.split("\n")[0])
        return f"{self.kind}:{text[:160]}"


def _on_alarm(signum, frame):
    raise Hang()


def run_one(target: Target, data: bytes, time_limit_s: float | None = 10.0, memory_limit: int | None = None) -> Outcome:
    """Run `target` on `data`. time_limit_s: a SIGALRM interrupts a longer run (main
    thread only; compiled loops are interrupted when they return to Python).
    memory_limit: with tracemalloc, an allocation peak above it (bytes) is a finding."""
    alarm = time_limit_s is not None and threading.current_thread() is threading.main_thread()
    if alarm:
        previous = signal.signal(signal.SIGALRM, _on_alarm)
        signal.setitimer(signal.ITIMER_REAL, time_limit_s)
    if memory_limit is not None:
        tracemalloc.start()
    start = time.perf_counter()
    outcome = Outcome(ACCEPTED)
    try:
        said = target.run(data)
        if said:
            outcome.error = str(said)
    except Hang:
        outcome = Outcome(HANG, f"over the {time_limit_s} s time limit")
    except MemoryError as exc:
        outcome = Outcome(MEMORY, f"MemoryError: {exc}", traceback.format_exc())
    except target.allowed as exc:
        outcome = Outcome(REFUSED, f"{type(exc).__name__}: {exc}")
    except Exception as exc:  # noqa: BLE001 - anything else is what fuzzing looks for
        outcome = Outcome(CRASH, f"{type(exc).__name__}: {exc}", traceback.format_exc())
    finally:
        if alarm:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
        outcome.seconds = time.perf_counter() - start
        if memory_limit is not None:
            outcome.peak_bytes = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
    if memory_limit is not None and outcome.peak_bytes > memory_limit and not outcome.finding:
        outcome = Outcome(
            MEMORY,
            f"allocated {outcome.peak_bytes} bytes at peak (bound {memory_limit}); "
            f"then {outcome.kind}: {outcome.error}",
            seconds=outcome.seconds,
            peak_bytes=outcome.peak_bytes,
        )
    return outcome


def input_id(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:16]


@dataclass
class LoopStats:
    executions: int = 0
    outcomes: dict = field(default_factory=dict)  # kind → count
    findings: list = field(default_factory=list)  # (data, Outcome), one per distinct signature
    corpus_size: int = 0
    seconds: float = 0.0

    def as_dict(self) -> dict:
        return {
            "executions": self.executions,
            "outcomes": dict(sorted(self.outcomes.items())),
            "findings": len(self.findings),
            "corpus": self.corpus_size,
            "seconds": round(self.seconds, 1),
        }


def mutation_loop(
    target: Target,
    corpus: list[bytes],
    seed: int = 0,
    executions: int | None = None,
    seconds: float | None = None,
    time_limit_s: float | None = 10.0,
    memory_limit: int | None = None,
    on_finding=None,
    max_corpus: int = 2000,
    on_execution=None,
) -> LoopStats:
    """Mutate corpus entries and run them until `executions` runs or `seconds` pass.
    An input whose outcome has a signature not seen before joins the corpus (the
    errors a reader can give stand in for coverage). Each finding is passed to
    `on_finding(data, outcome)` and kept once per signature. on_execution(data) is
    called before each run (a supervisor's record of the input in flight)."""
    rng = random.Random(seed)
    corpus = [bytes(c) for c in corpus] or [b""]
    seen: set[str] = set()
    stats = LoopStats()
    start = time.monotonic()
    pending = list(corpus)  # the seeds themselves run first
    while True:
        if executions is not None and stats.executions >= executions:
            break
        if seconds is not None and time.monotonic() - start >= seconds:
            break
        data = pending.pop(0) if pending else mutate(rng.choice(corpus), rng, corpus, target.structured)
        if on_execution is not None:
            on_execution(data)
        outcome = run_one(target, data, time_limit_s, memory_limit)
        stats.executions += 1
        stats.outcomes[outcome.kind] = stats.outcomes.get(outcome.kind, 0) + 1
        sig = outcome.signature()
        if sig not in seen:
            seen.add(sig)
            if outcome.finding:
                stats.findings.append((data, outcome))
                if on_finding is not None:
                    on_finding(data, outcome)
            elif len(corpus) < max_corpus and len(data) <= 1 << 18:
                corpus.append(data)
    stats.corpus_size = len(corpus)
    stats.seconds = time.monotonic() - start
    return stats
