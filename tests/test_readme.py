"""The README says what the project does today: the demo output it quotes is what the
default demo prints (`tools/readme_demo.py` rewrites the quote), and it stays short."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def _block(name: str) -> list[str]:
    text = README.read_text(encoding="utf-8")
    m = re.search(rf"<!-- {name} -->\n```\n(.*?)\n```\n<!-- /{name} -->", text, re.S)
    assert m, f"README has no {name} block"
    return m.group(1).splitlines()


def test_the_readme_quotes_what_the_default_demo_prints():
    # The default demo, as a user runs it (`graphsvc demo` in an empty folder); every
    # line but the timings is the same on every machine.
    from graphsvc.demo import format_demo_summary, run_demo

    printed = format_demo_summary(run_demo(Path("graphsvc-demo"))).splitlines()
    assert printed[-1].startswith("times: ")
    assert _block("demo-output") == printed[:-1]


def test_the_readme_is_short_enough_to_read():
    assert len(README.read_text(encoding="utf-8").splitlines()) <= 260
