"""Files written atomically: a temporary file in the destination folder, renamed over the target only once it
is complete, so an existing file is never half-overwritten and a failed write leaves nothing behind.

The one writer of the project's output files (EXR and PNG images, JSON and Markdown reports, plots).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable


class OutputError(OSError):
    """The output file cannot be written; the message names the path and the reason."""


def output_folder(path: str | os.PathLike) -> tuple[Path, Path]:
    """(path, its folder), or OutputError when the folder is missing or the path is a folder."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise OutputError(f"cannot write {path}: folder {folder} does not exist")
    if path.is_dir():
        raise OutputError(f"cannot write {path}: it is a folder")
    return path, folder


def check_writable(path: str | os.PathLike) -> Path:
    """Raise OutputError now if `path` cannot be written later (missing folder, a folder in its place, no write
    permission, a read-only file system): called before a render so that no work is lost at the end."""
    path, folder = output_folder(path)
    try:  # the real test: create (and remove) a temporary file where the output will go
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".check", dir=folder)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from exc
    os.close(fd)
    os.unlink(tmp)
    return path


def write_atomically(path: str | os.PathLike, write: Callable[[str], None], suffix: str = ".tmp") -> Path:
    """Call write(tmp_path) for a temporary file beside `path` (named .<name>.<random><suffix>, so writers that
    go by the extension see the right one), then rename it onto `path`. OutputError (an OSError) names the path
    when the folder is missing or the write fails; the temporary file is removed on any failure."""
    path, folder = output_folder(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=folder)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from exc
    os.close(fd)
    try:
        write(tmp)
        # mkstemp creates 0600 files; give the output the permissions a plain open() would (0666 & ~umask).
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(exc, OSError) and not isinstance(exc, OutputError):
            raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from exc
        raise
    return path


def write_bytes_atomically(path: str | os.PathLike, data: bytes, suffix: str = ".tmp") -> Path:
    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            f.write(data)

    return write_atomically(path, write, suffix)


def write_text_atomically(path: str | os.PathLike, text: str, suffix: str = ".tmp") -> Path:
    return write_bytes_atomically(path, text.encode("utf-8"), suffix)
