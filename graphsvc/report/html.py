"""The self-contained HTML page: the template with three.js, the viewer's script and
the report's data inlined (nothing is loaded from the network).

three.js (MIT licence, its header kept) is vendored as its single-file module build
(`vendor/three.module.min.js`); the module's closing `export{…}` becomes a plain
`THREE` object, so the page needs neither module loading nor a server and opens from
a file.
"""

from __future__ import annotations

import html
import json
import re
from functools import lru_cache
from importlib import resources

from graphsvc.fileio import write_text_atomic

_HERE = resources.files("graphsvc.report")
_PLACEHOLDER = re.compile(r"@@(TITLE|DATA|THREE|VIEWER)@@")


def _read(name: str) -> str:
    return (_HERE / name).read_text(encoding="utf-8")


@lru_cache(maxsize=1)
def three_script() -> str:
    """three.js as a classic script defining `THREE`: its licence header, then the
    module's body in a function returning the names it exported."""
    src = _read("vendor/three.module.min.js")
    header = re.match(r"\s*/\*\*.*?\*/", src, re.S)
    body = src[header.end() :] if header else src
    exports = re.search(r"export\s*\{([^}]*)\}\s*;?\s*$", body)
    if exports is None:
        raise RuntimeError("vendor/three.module.min.js does not end with an export list")
    pairs = []
    for item in exports.group(1).split(","):
        parts = item.split(" as ")
        local, name = parts[0].strip(), parts[-1].strip()
        pairs.append(f"{name}:{local}")
    body = body[: exports.start()]
    return (
        (header.group(0).strip() + "\n" if header else "")
        + 'const THREE=(function(){"use strict";'
        + body
        + "\nreturn{"
        + ",".join(pairs)
        + "};})();"
    )


def data_json(doc: dict) -> str:
    """The page's data as JSON safe inside a <script> element (sorted keys, no spaces;
    "<", ">" and "&" escaped)."""
    text = json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def render_html(doc: dict) -> str:
    """The page for `doc` ({"title", "clips": [clip_view...], "table": {...} or None})."""
    parts = {
        "TITLE": html.escape(str(doc.get("title", "graphsvc report"))),
        "DATA": data_json(doc),
        "THREE": three_script(),
        "VIEWER": _read("viewer.js"),
    }
    return _PLACEHOLDER.sub(lambda m: parts[m.group(1)], _read("template.html"))


def write_html(path, doc: dict) -> None:
    """Write the page atomically."""
    write_text_atomic(path, render_html(doc))
