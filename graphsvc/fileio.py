"""Atomic file output: write to a temporary file beside the target, fsync, rename.
A reader never sees a half-written file and a failed write leaves the old one intact."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from graphsvc.errors import GraphsvcError


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Yield a temporary path in the target's folder; on success it replaces `path`.
    `suffix` keeps tools that pick a format from the extension (matplotlib) happy."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise GraphsvcError(f"output folder {folder} does not exist")
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{path.name}.", suffix=suffix or path.suffix or ".tmp")
    os.close(fd)
    try:
        yield Path(tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_text_atomic(path, text: str) -> None:
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text)
