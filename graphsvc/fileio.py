"""Atomic file output: write to a temporary file beside the target, fsync, rename.
A reader never sees a half-written file and a failed write leaves the old one intact.
And reading input files: `require_file`, `read_input_bytes`, `read_input_text`,
`read_json_file`, a missing file, a folder, an unreadable or non-UTF-8 file as the
project's errors, worded one way."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from graphsvc.errors import FormatError, InputError, MissingFileError

StrPath = str | os.PathLike[str]  # a file's path as the functions take it


@contextlib.contextmanager
def atomic_writer(path) -> Iterator[IO[bytes]]:
    """Yield a binary file beside `path`; on normal exit it is flushed, fsynced and
    renamed onto `path`. On any error the temporary file is removed and an existing
    `path` is left untouched. A missing output folder raises InputError naming it.
    A process killed while writing leaves `path` as it was and its temporary file
    (`.NAME.HOST-PID.XXXX.tmp`), which the next write of `path` removes."""
    path = Path(path)
    folder = path.parent
    if not folder.is_dir():
        raise InputError(f"{path}: output folder {folder} does not exist")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, not a file")
    remove_stale_temporaries(path)
    tmp = tempfile.NamedTemporaryFile(dir=folder, prefix=f".{path.name}.{owner_tag()}.", suffix=".tmp", delete=False)
    try:
        with tmp as f:
            _crash_point("open", path)
            yield f
            f.flush()
            os.fsync(f.fileno())
        # NamedTemporaryFile creates 0600; give the result the mode a plain open()
        # would (or keep the mode of the file it replaces).
        os.chmod(tmp.name, _target_mode(path))
        _crash_point("rename", path)
        os.replace(tmp.name, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp.name)
        raise
    _fsync_dir(folder)


def owner_tag() -> str:
    """HOST-PID of this process, in a temporary file's (or folder's) name."""
    import socket

    return f"{socket.gethostname()}-{os.getpid()}"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # (EPERM: it exists, another user's)
        return True
    return True


def stale_temporary(tmp: Path, name: str) -> bool:
    """Whether `tmp`, a temporary of `name` (`.NAME.HOST-PID.XXXX.tmp`, a file or a
    folder), was left by a process of this host that no longer runs. Another host's,
    a live process's and names of another shape are not."""
    middle = tmp.name[len(name) + 2 : -len(".tmp")]
    owner = middle.rsplit(".", 1)[0]
    host, _, pid = owner.rpartition("-")
    if not tmp.name.startswith(f".{name}.") or not pid.isdigit():
        return False
    import socket

    return host == socket.gethostname() and int(pid) != os.getpid() and not _pid_alive(int(pid))


def remove_stale_temporaries(path) -> int:
    """Remove the temporary files a killed writer of `path` left beside it
    (`stale_temporary`); how many."""
    import glob

    path = Path(path)
    removed = 0
    for tmp in path.parent.glob(f".{glob.escape(path.name)}.*.tmp"):
        if stale_temporary(tmp, path.name):
            with contextlib.suppress(OSError):
                tmp.unlink()
                removed += 1
    return removed


def _crash_point(where: str, path: Path) -> None:
    """Test hook: GRAPHSVC_CRASH_AT=WHERE[:GLOB] kills this process with SIGKILL at
    that point of writing a file whose name matches GLOB ("open": the temporary file
    just made, "rename": written and synced, not yet in place), as a power cut or an
    OOM kill would. Unset in normal use."""
    hook = os.environ.get("GRAPHSVC_CRASH_AT")
    if not hook:
        return
    import fnmatch
    import signal

    point, _, pattern = hook.partition(":")
    if point == where and fnmatch.fnmatch(path.name, pattern or "*"):
        os.kill(os.getpid(), signal.SIGKILL)


def _target_mode(path: Path) -> int:
    try:
        return path.stat().st_mode & 0o7777
    except OSError:
        return 0o666 & ~_umask()


_UMASK: int | None = None


def _umask() -> int:
    global _UMASK
    if _UMASK is None:  # os.umask can only be read by setting it; do it once
        _UMASK = os.umask(0o022)
        os.umask(_UMASK)
    return _UMASK


def _fsync_dir(folder: Path) -> None:
    """Make the rename itself durable (POSIX); harmless to skip where unsupported."""
    with contextlib.suppress(OSError, AttributeError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def write_text_atomic(path, text: str) -> None:
    with atomic_writer(path) as f:
        f.write(text.encode("utf-8"))


def write_texts_atomic(items) -> None:
    """Write several files, given as (path, text or bytes) pairs, so that a crash never
    leaves a later one without the earlier ones: every file is written and synced beside
    its target first, then they are renamed into place in the order given (a reader who
    finds the last file finds them all, of the same run)."""
    items = [(Path(p), t) for p, t in items]
    with contextlib.ExitStack() as stack:
        # atomic_writer renames on leaving; the stack leaves in reverse: enter the last first
        files = [(stack.enter_context(atomic_writer(p)), t) for p, t in reversed(items)]
        for f, text in files:
            f.write(text if isinstance(text, bytes) else text.encode("utf-8"))


def require_file(path, what: str = "") -> Path:
    """`path` as a Path when it is a file; MissingFileError (or FormatError for a
    folder) otherwise. what: what the file is for, named in the message."""
    path = Path(path)
    if path.is_dir():
        raise FormatError(path, "is a folder, not a file")
    if not path.is_file():
        raise MissingFileError(path, what)
    return path


def read_input_bytes(path, what: str = "") -> bytes:
    """The file's bytes; a missing file, a folder or a file that cannot be read as the
    project's errors naming it."""
    path = Path(path)
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise MissingFileError(path, what) from None
    except IsADirectoryError:
        raise FormatError(path, "is a folder, not a file") from None
    except OSError as e:
        raise FormatError(path, f"cannot read: {e.strerror or e}") from None


def read_input_text(path, what: str = "", encoding: str = "utf-8") -> str:
    """The file's text (`read_input_bytes`); FormatError when it is not `encoding`."""
    data = read_input_bytes(path, what)
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as e:
        raise FormatError(path, f"not UTF-8 text ({e.reason} at byte {e.start})") from None


def read_json_file(path, what: str = ""):
    """The parsed content of a UTF-8 JSON file; FormatError naming the file (and the
    line) when it is missing, not UTF-8 or not valid JSON."""
    import json

    text = read_input_text(path, what)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise FormatError(path, f"not valid JSON: {exc.msg}", exc.lineno) from None


def file_sha256(path) -> str:
    """The SHA-256 of a file's bytes (hex), read in blocks."""
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def same_file(a, b) -> bool:
    """Whether two paths name one file: the same resolved path, or (both existing) the
    same inode, as a hard link or a symbolic link to it would."""
    a, b = Path(a), Path(b)
    with contextlib.suppress(OSError):
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    return a.resolve() == b.resolve()


def check_outputs(outputs, inputs=()) -> None:
    """Refuse, before anything is read or written, output paths that would lose data or
    that the command would write in a form nobody reads back. outputs: (option, path,
    suffixes) triples — suffixes the accepted ones (lower case, with the dot) or None
    for any; inputs: (what, path) pairs, what the input is (e.g. "the recording").
    InputError naming the option when a path is empty, its folder is missing, it is a
    folder, its suffix is not accepted, it names an input, or two outputs name one file.
    None paths (an option not given) are skipped."""
    given = [(opt, Path(p), sfx) for opt, p, sfx in outputs if p is not None]
    for opt, path, suffixes in given:
        if str(path) in ("", "."):
            raise InputError(f"{opt}: an empty path is not a file")
        if not path.parent.is_dir():
            raise InputError(f"{path}: output folder {path.parent} does not exist")
        if path.is_dir():
            raise InputError(f"{path}: is a folder, not a file ({opt})")
        for what, source in inputs:
            if source is not None and str(source) != "" and same_file(path, source):
                raise InputError(f"{path}: {opt} would overwrite {what}; give another output path")
    for k, (opt, path, _) in enumerate(given):
        for other, other_path, _ in given[:k]:
            if same_file(path, other_path):
                raise InputError(f"{path}: {opt} and {other} name the same file; give each its own")
    for opt, path, suffixes in given:
        suffix = path.suffix.lower()
        accepted = suffixes and " or ".join(filter(None, (", ".join(suffixes[:-1]), suffixes[-1])))
        if suffix in (".glb", ".gltf") and (suffixes is None or suffix not in suffixes):  # (motion.output's glTF)
            writes = "does not write" if suffixes is None else f"writes {accepted}, not"
            raise InputError(
                f"{path}: {opt} {writes} glTF ({path.suffix}): only a reconstructed motion is written as "
                "glTF (synthesize, batch, the client)"
            )
        if suffixes is not None and suffix not in suffixes:
            raise InputError(f"{path}: {opt} writes {accepted}, not {path.suffix or 'a file without a suffix'}")
