"""Atomic file replacement: a reader sees the old file or the whole new one, never a torn one.

The one place PDIC writes a file it may be replacing (light maps, manifest,
records, cache entries). bpy-free.
"""
from __future__ import annotations

import errno
import os
import shutil
import uuid
from pathlib import Path
from typing import Callable


def default_mode() -> int:
    """The mode ``open(path, "w")`` would give a new file: 0o666 minus the process umask."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def temporary_sibling(path: Path, tag: str = "tmp") -> Path:
    """A unique hidden name next to ``path`` keeping its suffix (writers that look at the suffix see it)."""
    return path.with_name(f".{path.stem}.pdic-{tag}-{uuid.uuid4().hex[:8]}{path.suffix}")


def describe_os_error(error: OSError, folder: Path) -> str:
    """A message for a failed write that says what the user can do (a full disk says so)."""
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        free = None
    if error.errno in (errno.ENOSPC, errno.EDQUOT) or (free is not None and free < 1 << 20):
        shown = f" ({free // 1024} KiB free)" if free is not None else ""
        return f"no space left on the disk holding {str(folder)!r}{shown}; free some space or choose another folder"
    return error.strerror or str(error)


def write_atomic(path, write: Callable[[Path], None], mode: int | None = None) -> Path:
    """Write ``path`` through ``write(temporary_path)`` and rename it into place.

    path : the file to create or replace.
    write : writes the whole file at the path it is given (a sibling of ``path``).
    mode : permission bits of the result; default :func:`default_mode` (not mkstemp's 0o600).

    Raises whatever ``write`` raises, or OSError; ``path`` is then unchanged and no
    temporary file is left behind.
    """
    path = Path(path)
    tmp = temporary_sibling(path)
    try:
        write(tmp)
        if not tmp.exists():
            raise OSError(errno.EIO, "the writer did not create the file", str(path))
        os.chmod(tmp, default_mode() if mode is None else mode)
        os.replace(tmp, path)
    except BaseException:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise
    return path


def write_text_atomic(path, text: str, mode: int | None = None) -> Path:
    """:func:`write_atomic` for a UTF-8 text file."""
    return write_atomic(path, lambda p: Path(p).write_text(text, encoding="utf-8"), mode)
