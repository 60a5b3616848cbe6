"""Rewrite the README's quoted demo output (the block between `<!-- demo-output -->`
markers) with what the default `graphsvc demo` prints now, its machine-dependent
timings line left out. tests/test_readme.py checks the two agree.

    python tools/readme_demo.py [--check]

Runs the demo in a temporary folder (as a user runs it, `-o graphsvc-demo`); prints
JSON: {"changed": bool, "lines": N}. --check: change nothing, exit 1 if the README is
stale."""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import tempfile
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def demo_lines() -> list[str]:
    from graphsvc.demo import format_demo_summary, run_demo

    here = os.getcwd()
    with tempfile.TemporaryDirectory(prefix="graphsvc-readme-") as folder:
        os.chdir(folder)
        try:
            lines = format_demo_summary(run_demo(Path("graphsvc-demo"))).splitlines()
        finally:
            os.chdir(here)
    return [line for line in lines if not line.startswith("times: ")]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if the README is stale; change nothing")
    args = ap.parse_args()
    text = README.read_text(encoding="utf-8")
    pattern = re.compile(r"(<!-- demo-output -->\n```\n)(.*?)(\n```\n<!-- /demo-output -->)", re.S)
    if not pattern.search(text):
        print("README.md has no demo-output block", file=sys.stderr)
        return 2
    lines = demo_lines()
    new = pattern.sub(lambda m: m.group(1) + "\n".join(lines) + m.group(3), text)
    changed = new != text
    if changed and not args.check:
        from graphsvc.fileio import write_text_atomic

        write_text_atomic(README, new)
    print(json.dumps({"changed": changed, "lines": len(lines)}))
    return 1 if changed and args.check else 0


if __name__ == "__main__":
    sys.exit(main())
