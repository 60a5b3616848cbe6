"""The README says what the project does today: the demo output it quotes is what the
default demo prints (`tools/readme_demo.py` rewrites the quote), and it stays short."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"
# A figure and its unit: "1.7 cm", "47,331 nodes", "82 %", "7.7°".
FIGURE = re.compile(r"(\d[\d,]*(?:\.\d+)?)( ?(?:cm|°|%|g\b|nodes|edges))?")

# How far a figure of the demo may move between processors, by its unit (relative for
# counts): bytes are the same for the same input, seed and machine, but numpy's and
# OpenBLAS's kernels differ between processors (AVX-512 or not: their sin, cos and
# products round differently in the last bit), and the build's thresholds and the
# search's near-ties turn an ulp into another bridge or another step. A figure with no
# unit (clips, frames, samples, seconds, weights) is exact.
TOLERANCE = {
    "cm": (0.4, 0.0),
    "°": (1.5, 0.0),
    "%": (3.0, 0.0),
    "g": (0.1, 0.0),
    "nodes": (0, 0.03),
    "edges": (0, 0.03),
}


def _block(name: str) -> list[str]:
    text = README.read_text(encoding="utf-8")
    m = re.search(rf"<!-- {name} -->\n```\n(.*?)\n```\n<!-- /{name} -->", text, re.S)
    assert m, f"README has no {name} block"
    return m.group(1).splitlines()


def _same_but_for_rounding(quoted: str, printed: str) -> bool:
    if quoted.startswith("  path:"):  # (the actions of the path the search found: where it starts)
        return quoted.split(" → ")[0] == printed.split(" → ")[0]
    if FIGURE.sub("#", quoted) != FIGURE.sub("#", printed):
        return False
    for q, p in zip(FIGURE.finditer(quoted), FIGURE.finditer(printed), strict=True):
        unit = (q.group(2) or "").strip()
        if unit != (p.group(2) or "").strip():
            return False
        x, y = (float(m.group(1).replace(",", "")) for m in (q, p))
        absolute, relative = TOLERANCE.get(unit, (0.0, 0.0))
        if abs(x - y) > max(absolute, relative * abs(x)) + 1e-9:
            return False
    return True


def test_the_readme_quotes_what_the_default_demo_prints():
    # The default demo, as a user runs it (`graphsvc demo` in an empty folder): every
    # line but the timings as it prints here, its figures within TOLERANCE.
    from graphsvc.demo import format_demo_summary, run_demo

    printed = format_demo_summary(run_demo(Path("graphsvc-demo"))).splitlines()
    assert printed[-1].startswith("times: ")
    quoted = _block("demo-output")
    assert len(quoted) == len(printed) - 1
    for q, p in zip(quoted, printed, strict=False):
        assert _same_but_for_rounding(q, p), (q, p)


def test_the_tolerance_tells_rounding_from_change():
    graph = "motion graph: 46,492 nodes, 61,713 edges"
    assert _same_but_for_rounding(graph, "motion graph: 47,331 nodes, 62,651 edges")
    assert not _same_but_for_rounding(graph, "motion graph: 52,000 nodes, 61,713 edges")
    assert not _same_but_for_rounding(graph, "motion graph: 46,492 nodes, 61,713 links")
    rec = "reconstruction (weights 0.5,1,1): joint error 1.7 cm, root error 2.3 cm, heading error 7.7°, label right 82 % of frames"
    assert _same_but_for_rounding(rec, rec.replace("2.3 cm", "2.4 cm").replace("7.7°", "7.5°"))
    assert not _same_but_for_rounding(rec, rec.replace("1.7 cm", "2.7 cm"))
    assert not _same_but_for_rounding(rec, rec.replace("7.7°", "9.7°"))
    assert not _same_but_for_rounding(rec, rec.replace("0.5,1,1", "0.5,1,2"))
    assert _same_but_for_rounding("  path: idle → walk → run", "  path: idle → run")
    assert not _same_but_for_rounding("  path: idle → walk", "  path: walk → idle")
    assert not _same_but_for_rounding("wrote graphsvc-demo/: kb/*.bvh", "wrote graphsvc-demo/: kb/*.bvh, x")


def test_the_readme_is_short_enough_to_read():
    assert len(README.read_text(encoding="utf-8").splitlines()) <= 260
