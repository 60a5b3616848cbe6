"""Finding and loading motion files of any supported format, with their labels:
BVH, ASF/AMC and DeepMimic JSON (`.txt`, told from other text files by its content).

Labels: the content label first, then user tags. The content label comes from a
Bandai-style sidecar `<stem>.json` ({"content": id, ...}) whose id indexes the
lines of `../cfg/content*.txt` (0-based, e.g. "dataset-1_walk" → "walk"); without
them it is derived from the file name (`dataset-2_walk_normal_001` → "walk", a
DeepMimic `humanoid3d_walk.txt` → "walk", any other name → its stem, e.g. CMU
"02_01"). User tags are read from an optional sidecar `<stem>.tags`, one per line
('#' starts a comment).
"""

from __future__ import annotations

import fnmatch
import functools
import glob
import json
import os
import re
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from graphsvc.errors import FormatError, InputError, MissingFileError, UnknownFormatError
from graphsvc.fileio import StrPath, read_input_text
from graphsvc.motion.asfamc import read_asf_amc
from graphsvc.motion.bvh import read_bvh
from graphsvc.motion.deepmimic import clip_label, is_deepmimic, may_be_deepmimic, read_deepmimic
from graphsvc.motion.skeleton import Motion, check_finite

MOTION_SUFFIXES = (".bvh", ".amc", ".txt")  # .txt: DeepMimic JSON (collected from folders when it looks like one)
_BANDAI_NAME = re.compile(r"^dataset-\d+_(?P<content>[^_]+)_(?P<style>[^_]+)_\d+$")
_GLOB_CHARS = re.compile(r"[*?\[]")


def _check_suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix == ".asf":
        raise UnknownFormatError(
            f"{path}: an .asf file is a skeleton only; pass the .amc motion file "
            "(the .asf beside it is found automatically)"
        )
    if suffix not in MOTION_SUFFIXES:
        raise UnknownFormatError(
            f"{path}: unknown motion format {suffix or '(no extension)'!r}; expected .bvh, .amc or a DeepMimic .txt"
        )
    if suffix == ".txt" and path.is_file() and not may_be_deepmimic(path):
        raise UnknownFormatError(
            f"{path}: unknown motion format: a .txt motion file is DeepMimic JSON "
            '({"Frames": [...]}), and this file is not JSON'
        )
    return suffix


def _read_label_file(path: Path) -> list[str]:
    return read_input_text(path).splitlines()


@functools.lru_cache(maxsize=64)
def _content_table(path: Path) -> tuple[str, ...]:
    # One table serves hundreds of clips: read it once per process.
    return tuple(n.strip() for n in _read_label_file(path))


def content_label(path) -> str:
    """The clip's content label (see module docstring)."""
    path = Path(path)
    sidecar = path.with_suffix(".json")
    if sidecar.is_file():
        try:
            meta = json.loads(sidecar.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise FormatError(sidecar, f"not valid JSON: {exc}") from None
        content = meta.get("content") if isinstance(meta, dict) else None
        cfg = path.parent.parent / "cfg"
        tables = sorted(cfg.glob("content*.txt")) if cfg.is_dir() else []
        if isinstance(content, int) and not isinstance(content, bool) and tables:
            names = _content_table(tables[0])
            if not 0 <= content < len(names) or not names[content]:
                raise FormatError(sidecar, f"content id {content} is not a line of {tables[0]} ({len(names)} lines)")
            label = names[content]
            # "dataset-1_walk" → "walk": drop the dataset prefix the table repeats.
            prefix = path.parent.parent.name + "_"
            if label.startswith(prefix):
                label = label[len(prefix) :]
            return re.sub(r"^dataset-\d+_", "", label)
        if isinstance(content, str) and content:
            return content
    if path.suffix.lower() == ".txt":
        return clip_label(path.stem)
    m = _BANDAI_NAME.match(path.stem)
    if m:
        return m.group("content")
    # "walk_03" → "walk": a trailing take number is not part of the content, unless
    # nothing but numbers would remain (CMU "01_01" keeps its whole stem).
    stripped = re.sub(r"[_-]\d+$", "", path.stem)
    return stripped if re.search(r"[^\d_-]", stripped) else path.stem


def user_tags(path) -> list[str]:
    """Tags from the optional sidecar `<stem>.tags`, one per line, in order."""
    sidecar = Path(path).with_suffix(".tags")
    if not sidecar.is_file():
        return []
    tags = []
    for line in _read_label_file(sidecar):
        tag = line.split("#", 1)[0].strip()
        if tag and tag not in tags:
            tags.append(tag)
    return tags


_READERS: dict[str, Callable[..., Motion]] = {".bvh": read_bvh, ".amc": read_asf_amc, ".txt": read_deepmimic}


def load_motion(path: StrPath, **options: Any) -> Motion:
    """Load one .bvh, .amc or DeepMimic .txt file (options go to read_bvh /
    read_asf_amc / read_deepmimic, e.g. scale=, asf_path=, rate_hz=), with name, source
    and labels filled in."""
    path = Path(path)
    motion = _READERS[_check_suffix(path)](path, **options)
    content = content_label(path)
    labels = [content] + [t for t in user_tags(path) if t != content]
    motion.name = path.stem
    motion.source = str(path)
    motion.labels = tuple(labels)
    check_finite(motion)
    return motion


def _excluded(path: Path, exclude) -> bool:
    text = path.as_posix()
    return any(fnmatch.fnmatch(path.name, pat) or fnmatch.fnmatch(text, pat) for pat in exclude)


def is_motion_file(path: StrPath) -> bool:
    """Whether a file named directly is read as motion: .bvh, .amc, or a .txt file
    that starts with a JSON object (DeepMimic)."""
    suffix = Path(path).suffix.lower()
    return suffix in MOTION_SUFFIXES and (suffix != ".txt" or may_be_deepmimic(path))


def _collected(f: Path) -> bool:
    """Whether a folder scan or a pattern collects `f`: a .bvh or .amc file, or a .txt
    file that looks like a DeepMimic motion file (other .txt files, such as a
    dataset's label tables, are passed over)."""
    suffix = f.suffix.lower()
    return suffix in MOTION_SUFFIXES and f.is_file() and (suffix != ".txt" or is_deepmimic(f))


def find_motion_files(paths: StrPath | Iterable[StrPath], exclude: str | Iterable[str] = ()) -> list[Path]:
    """Motion files named by `paths`: files, folders (searched recursively) or glob
    patterns ('**' recurses). Only .bvh/.amc files and DeepMimic .txt files are
    collected from folders and patterns; a file named directly must be one. `exclude`:
    fnmatch patterns matched against the file name or the whole path. Sorted, without
    duplicates."""
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    exclude = [exclude] if isinstance(exclude, str) else list(exclude)
    found: set[Path] = set()
    for item in paths:
        text = os.fspath(item) if isinstance(item, os.PathLike) else str(item)
        if not text.strip():
            raise InputError("an empty path is not a file or folder")
        p = Path(text)
        if p.is_file():
            _check_suffix(p)
            found.add(p)
        elif p.is_dir():
            found.update(f for f in p.rglob("*") if _collected(f))
        elif _GLOB_CHARS.search(text):
            hits = [Path(h) for h in glob.glob(text, recursive=True)]
            files: set[Path] = set()
            for h in hits:
                if h.is_dir():
                    files.update(f for f in h.rglob("*") if _collected(f))
                elif _collected(h):
                    files.add(h)
            if not files:
                raise FormatError(text, "no such file: the pattern matches no .bvh, .amc or DeepMimic .txt files")
            found.update(files)
        else:
            raise MissingFileError(text)
    return sorted((f for f in found if not _excluded(f, exclude)), key=lambda f: f.as_posix())


def load_motions(paths: StrPath | Iterable[StrPath], exclude: str | Iterable[str] = (), **options: Any) -> list[Motion]:
    """load_motion over find_motion_files(paths, exclude)."""
    return [load_motion(p, **options) for p in find_motion_files(paths, exclude)]
