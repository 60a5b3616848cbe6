"""A batch manifest: the items to reconstruct, read from CSV (a header row) or JSON (a
list of objects, or {"items": [...]}).

Columns: `recording`, `graph` (a name given with `--graph NAME=PATH`, or a path),
`strategy` and `output` (a name, no extension) are required; `weights`, `constraints`,
`calibration`, `format` (what the output is written as: bvh, the default, glb or gltf)
and `options` (a JSON object of `synthesize` flags without their dashes, e.g.
{"beam": 10, "olng-k": 64, "device-map": "xsens", "height": 1.82}) are optional.
Relative paths are taken from the manifest's folder.

What does not parse — a row, a column, a duplicate output — fails the whole manifest
(FormatError naming the line) before anything runs. What parses but cannot run — a
missing recording, an unknown graph, options `synthesize` would refuse — is the
item's own failure (`plan_item`), so the rest of the batch still runs.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

from graphsvc.errors import FormatError, GraphsvcError, InputError
from graphsvc.fileio import file_sha256, read_input_text, require_file
from graphsvc.flags import add_performer_flags, add_synthesize_flags, calibration_choice, options_from_flags, os_message
from graphsvc.graph.file import graph_file_meta
from graphsvc.motion.output import MOTION_OUTPUT_SUFFIXES
from graphsvc.motion.proportions import performer_segments
from graphsvc.store import file_checksum
from graphsvc.strategies import check_options

REQUIRED = ("recording", "graph", "strategy", "output")
OPTIONAL = ("weights", "constraints", "calibration", "format", "options")
COLUMNS = REQUIRED + OPTIONAL
# Flags an item's options may not give: they are columns, or the batch decides them.
RESERVED_FLAGS = {"strategy", "weights", "constraints", "calibration", "format", "report", "output", "o", "help", "h"}
# Option values that name a file: taken from the manifest's folder when one is there.
PATH_FLAGS = ("device-map", "markers", "performer", "performer-mapping")
OUTPUT_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+@=-]*$")
FORMATS = tuple(s[1:] for s in MOTION_OUTPUT_SUFFIXES)  # an item's output: NAME.bvh (the default), .glb, .gltf


@dataclass(frozen=True)
class Item:
    """One manifest row, parsed (not yet checked against the files it names)."""

    line: int  # where it is in the manifest (CSV: its line; JSON: its position from 1)
    output: str
    recording: str
    graph: str
    strategy: str
    weights: str | None = None
    constraints: str | None = None
    calibration: str | None = None
    format: str | None = None  # None: bvh
    options: dict = field(default_factory=dict)


def read_manifest(path) -> list[Item]:
    """Every item of a manifest; FormatError (file and line) for a row that does not
    parse, an unknown column, a missing required value or a duplicate output name."""
    path = Path(path)
    text = read_input_text(path, "manifest")
    rows = _json_rows(path, text) if path.suffix.lower() == ".json" else _csv_rows(path, text)
    items, seen = [], {}
    for line, row in rows:
        item = _item(path, line, row)
        if item.output in seen:
            raise FormatError(
                path, f"output {item.output!r} is also line {seen[item.output]}'s (outputs must differ)", line
            )
        seen[item.output] = line
        items.append(item)
    if not items:
        raise FormatError(path, "the manifest lists no items")
    return items


def _csv_rows(path: Path, text: str):
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    try:
        header = None
        for row in reader:
            if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
                continue
            if header is None:
                header = [h.strip().lower() for h in row]
                unknown = [h for h in header if h not in COLUMNS]
                if unknown:
                    raise FormatError(
                        path, f"unknown column {unknown[0]!r} (columns: {', '.join(COLUMNS)})", reader.line_num
                    )
                missing = [c for c in REQUIRED if c not in header]
                if missing:
                    raise FormatError(
                        path,
                        f"the header lacks column {missing[0]!r} (required: {', '.join(REQUIRED)})",
                        reader.line_num,
                    )
                continue
            if len(row) != len(header):
                raise FormatError(path, f"{len(row)} fields, the header has {len(header)}", reader.line_num)
            yield reader.line_num, dict(zip(header, row))
    except csv.Error as exc:
        raise FormatError(path, f"not valid CSV: {exc}", reader.line_num) from None
    if header is None:
        raise FormatError(path, "no header row (columns: " + ", ".join(REQUIRED) + ", …)")


def _json_rows(path: Path, text: str):
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"not valid JSON: {exc.msg}", exc.lineno) from None
    if isinstance(data, dict) and set(data) == {"items"}:
        data = data["items"]
    if not isinstance(data, list):
        raise FormatError(path, 'a JSON manifest is a list of items (or {"items": [...]})')
    for k, row in enumerate(data, 1):
        if not isinstance(row, dict):
            raise FormatError(path, f"item {k} is not an object", k)
        unknown = [c for c in row if c not in COLUMNS]
        if unknown:
            raise FormatError(path, f"item {k}: unknown field {unknown[0]!r} (fields: {', '.join(COLUMNS)})", k)
        yield k, row


def _item(path: Path, line: int, row: dict) -> Item:
    values = {}
    for c in COLUMNS:
        v = row.get(c)
        if c == "options" and isinstance(v, dict):
            values[c] = v
            continue
        if v is not None and not isinstance(v, str):
            if c == "weights" and isinstance(v, list):
                v = ",".join(str(x) for x in v)
            else:
                raise FormatError(path, f"{c} must be text, got {json.dumps(v)}", line)
        v = (v or "").strip()
        if c in REQUIRED and not v:
            raise FormatError(path, f"no {c} (required: {', '.join(REQUIRED)})", line)
        values[c] = v or None
    if not OUTPUT_NAME.match(values["output"]) or values["output"].lower().endswith((*MOTION_OUTPUT_SUFFIXES, ".json")):
        raise FormatError(
            path,
            f"output {values['output']!r} must be a plain name (letters, digits, . _ - +), no "
            "folder and no extension (the format column chooses .bvh, .glb or .gltf)",
            line,
        )
    if values["format"] is not None:
        values["format"] = values["format"].lower().lstrip(".")
        if values["format"] not in FORMATS:
            raise FormatError(path, f"format {values['format']!r} is not one of {', '.join(FORMATS)}", line)
    options = values.pop("options") or {}
    if isinstance(options, str):
        try:
            options = json.loads(options)
        except json.JSONDecodeError as exc:
            raise FormatError(path, f"options are not valid JSON: {exc.msg}", line) from None
    if not isinstance(options, dict):
        raise FormatError(path, 'options must be a JSON object of synthesize flags, e.g. {"beam": 10}', line)
    return Item(line=line, options=options, **values)


@dataclass(frozen=True)
class Plan:
    """An item checked against its files: what a worker runs (`task`) and the
    fingerprint of everything its output depends on; or why it cannot run."""

    item: Item
    task: dict | None
    fingerprint: str
    error: str | None = None


def plan_item(item: Item, folder: Path, graphs: dict, out_dir: Path, version: str) -> Plan:
    """Resolve an item's files (relative to `folder`, the manifest's), check its options
    as `synthesize` would, and fingerprint it: the graph's and recording's checksums,
    the strategy and flags, the constraints' contents, `version`. graphs: {name: path}
    of `--graph NAME=PATH`. A missing file, an unknown graph or bad options give a
    Plan with `error` (the item fails, the batch goes on)."""
    try:
        argv = option_argv(item, folder)
        _, args = parse_item_options(argv)  # refused here as synthesize would refuse it
        if args.performer is not None:  # (a bad performer file: this item's failure)
            performer_segments(require_file(args.performer, "performer"), args.performer_mapping)
        elif args.performer_mapping is not None:
            raise InputError("options: performer-mapping applies to a performer motion file")
        graph_path = _graph_path(item.graph, folder, graphs)
        recording = _existing(folder, item.recording, "recording")
        meta = graph_file_meta(graph_path)
        if meta.get("kind") not in (None, "graph"):
            raise InputError(f"graph {item.graph}: {graph_path} is a {meta.get('kind')} file, not a graph")
        checksum = file_checksum(graph_path)
        parts = {
            "version": version,
            "graph": checksum,
            "recording": file_sha256(recording),
            "argv": argv,
            "constraints": file_sha256(
                Path(item.constraints if Path(item.constraints).is_absolute() else folder / item.constraints)
            )
            if item.constraints
            else None,
            "calibration": file_sha256(_existing(folder, item.calibration, "calibration"))
            if item.calibration
            else None,
            **({"performer": file_sha256(args.performer)} if args.performer is not None else {}),
            **({"format": item.format} if item.format not in (None, "bvh") else {}),
        }
    except (GraphsvcError, OSError) as exc:
        reason = str(exc) if isinstance(exc, GraphsvcError) else os_message(exc)
        return Plan(item, None, _digest({"error": reason, "item": repr(item), "version": version}), error=reason)
    task = {
        "output": item.output,
        "out_dir": str(out_dir),
        "graph": str(graph_path),
        "graph_checksum": checksum,
        "recording": str(recording),
        "argv": argv,
        "format": item.format or "bvh",
    }
    return Plan(item, task, _digest(parts))


def option_argv(item: Item, folder: Path) -> list[str]:
    """The item's `synthesize` flags: --strategy, --weights, --constraints and
    --calibration (from the manifest's folder) and its options, in a fixed order."""
    argv = ["--strategy", item.strategy]
    if item.weights:
        argv += ["--weights", item.weights]
    if item.constraints:
        argv += ["--constraints", str(_existing(folder, item.constraints, "constraints"))]
    if item.calibration:
        argv += ["--calibration", str(_existing(folder, item.calibration, "calibration"))]
    for key in sorted(item.options):
        flag = str(key).strip().lstrip("-").replace("_", "-")
        if flag in RESERVED_FLAGS:
            raise InputError(
                f"options: {key!r} is not an option here (strategy, weights, constraints and calibration are columns)"
            )
        value = item.options[key]
        if value is True:
            argv.append(f"--{flag}")
        elif value is False or value is None:
            continue
        elif isinstance(value, (str, int, float)):
            text = str(value)
            if flag in PATH_FLAGS and (folder / text).is_file():
                text = str((folder / text).resolve())
            argv += [f"--{flag}", text]
        elif isinstance(value, list) and all(isinstance(v, (str, int, float)) for v in value):
            argv += [f"--{flag}", ",".join(str(v) for v in value)]
        else:
            raise InputError(f"options: {key!r} must be a number, text, a list or true, got {json.dumps(value)}")
    return argv


class _ItemParser:
    """The `synthesize` flags (`graphsvc.flags`), parsed into the values
    `options_from_flags` reads; a flag it refuses raises InputError instead of exiting."""

    _parser = None

    @classmethod
    def get(cls):
        if cls._parser is None:

            class Raising(argparse.ArgumentParser):
                def error(self, message):
                    raise InputError(f"options: {message}")

            p = Raising(prog="options", add_help=False, allow_abbrev=False)
            add_synthesize_flags(p)
            add_performer_flags(p)
            cls._parser = p
        return cls._parser


def parse_item_options(argv: list[str]):
    """(Options, the parsed flags) of an item's flags, checked as `synthesize` checks
    them: InputError or FormatError for what it would refuse."""
    args = _ItemParser.get().parse_args(argv)
    calibration_choice(args)
    options, _ = options_from_flags(args)  # (another strategy's options: kept, listed as ignored in its report)
    return check_options(options), args


def _graph_path(graph: str, folder: Path, graphs: dict) -> Path:
    if graph in graphs:
        return Path(graphs[graph]).resolve()
    path = Path(graph) if Path(graph).is_absolute() else folder / graph
    if path.is_file():
        return path.resolve()
    known = f" (graphs given: {', '.join(sorted(graphs))})" if graphs else " (give --graph NAME=PATH to name one)"
    raise InputError(f"unknown graph {graph!r}: neither a --graph name nor a file{known}")


def _existing(folder: Path, name: str, what: str) -> Path:
    path = Path(name) if Path(name).is_absolute() else folder / name
    return require_file(path, what).resolve()


def _digest(parts: dict) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()[:32]
