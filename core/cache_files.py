"""Checksummed cache files that cannot run code when read: ``.npz`` arrays plus a JSON header.

Used by the unwrap cache and :class:`core.bake_cache.BakeCache`. A file holds named
arrays and one JSON header (stored as the uint8 array ``__header__``); the header
carries a sha256 over the header's other fields and every array's name, dtype,
shape and bytes. :func:`read_entry` returns None for anything that is not exactly
what was written (missing, zero-length, truncated, a flipped byte, a foreign
file), so callers recompute instead of failing or using a damaged value. Arrays
are read with ``allow_pickle=False``: no object arrays, no code on load.
"""
from __future__ import annotations

import hashlib
import json
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np

FORMAT = "pdic-cache-1"
HEADER = "__header__"


def _digest(header: dict, arrays: dict) -> str:
    h = hashlib.sha256()
    h.update(json.dumps(header, sort_keys=True).encode())
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"\0{name}\0{a.dtype.str}\0{a.shape}\0".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def write_entry(path: Path, header: dict, arrays: dict) -> None:
    """Write ``arrays`` (name -> ndarray, no object dtype) and a JSON-able ``header`` to
    ``path`` atomically (a concurrent reader sees the old file or the whole new one).

    Raises OSError when the folder cannot be written (full disk, read-only, missing rights).
    """
    if HEADER in arrays:
        raise ValueError(f"cache entry: array name {HEADER!r} is reserved")
    full = {"format": FORMAT, **header}
    full["sha256"] = _digest(full, arrays)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-", suffix=".npz", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            blob = np.frombuffer(json.dumps(full, sort_keys=True).encode(), np.uint8)
            np.savez(f, **{HEADER: blob}, **arrays)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def read_entry(path: Path) -> tuple[dict, dict] | None:
    """(header, arrays) of a file :func:`write_entry` wrote, or None if it is missing,
    unreadable or does not match its checksum."""
    try:
        with np.load(Path(path), allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
        header = json.loads(arrays.pop(HEADER).tobytes().decode())
    except (OSError, KeyError, ValueError, EOFError, UnicodeDecodeError, zipfile.BadZipFile, AttributeError):
        return None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        return None
    stored = header.pop("sha256", None)
    if stored != _digest(header, arrays):
        return None
    header.pop("format")
    return header, arrays
