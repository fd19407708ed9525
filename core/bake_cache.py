"""Explicit, content-keyed reuse of bake intermediates between bakes (STYLE.md principle 8).

A :class:`BakeCache` is an object the caller owns and passes to
:func:`core.pipeline.bake`: kept in memory (core API, tests, the bench) and,
when given a folder, also on disk (the add-on passes its cache folder). There
is no module-level state: two caches never see each other's entries.

What is stored, and what its key hashes (every key also hashes the source
code of ``core/`` so an edited algorithm never serves stale results):

==============  ====================================================================
kind            key
==============  ====================================================================
``raster``      one target: its triangles' positions and normals, light-map UVs,
                resolution; ``texel_samples``
``direct``      the raster key + light transport (see :func:`transport_key`) +
                ``direct_samples``, ``seed``
``photons``     light transport + ``photons``, photon bounces, ``seed``; with
                ``density_control`` on, its n and the Algorithm 1 parameters
``cache``       the photons key + Algorithm 1 parameters (a, r_nearest, R_min,
                R_max) + refinement settings (quality, hemisphere, reuse)
``indirect``    the cache key + the raster key + ``gradients``
==============  ====================================================================

Light transport is everything light depends on: all triangles (baked or not),
their shading normals, texture UVs and materials, textures, lights and the
world. Light-map resolutions and which objects are baked are *not* part of it,
so changing one object's resolution reuses the photon map (and the cache, as
long as R_min, tied to the coarsest texel, is unchanged) and redoes only that
object's texels.
"""
from __future__ import annotations

import dataclasses
import hashlib
import importlib
import os
from pathlib import Path

import numpy as np

from .cache_files import read_entry, write_entry

FORMAT_VERSION = 2
"""Bump when the stored layout changes."""
KINDS = ("raster", "direct", "photons", "cache", "indirect")


def _update(h, value) -> None:
    """Feed ``value`` (arrays, numbers, strings, dataclasses, sequences, dicts) into hash ``h``."""
    if isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        h.update(f"A{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        h.update(f"D{type(value).__name__}".encode())
        for f in dataclasses.fields(value):
            h.update(f.name.encode())
            _update(h, getattr(value, f.name))
    elif isinstance(value, dict):
        h.update(b"M")
        for k in sorted(value, key=str):
            _update(h, str(k))
            _update(h, value[k])
    elif isinstance(value, (list, tuple)):
        h.update(f"L{len(value)}".encode())
        for v in value:
            _update(h, v)
    else:
        h.update(f"S{type(value).__name__}:{value!r}".encode())
    h.update(b"\0")


def content_hash(*parts) -> str:
    """sha256 hex digest of ``parts`` (arrays by dtype, shape and bytes; others by repr)."""
    h = hashlib.sha256()
    for part in parts:
        _update(h, part)
    return h.hexdigest()


def code_hash() -> str:
    """sha256 of the ``core/`` sources: results of edited code are never reused."""
    folder = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for path in sorted(folder.glob("*.py")):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def transport_key(scene) -> str:
    """Hash of everything light transport depends on (not targets, not resolutions, not origin)."""
    g = scene.geometry
    transmissive = (g.transmission,) if g.transmission.any() else ()  # opaque scenes keep their keys
    portals = (scene.portals,) if scene.portals else ()  # so do scenes without portals
    return content_hash("transport", g.positions, g.normals, g.uvs, g.material, scene.materials,
                        scene.textures, scene.lights, scene.world, *transmissive, *portals)


def target_key(scene, target, texel_samples: int) -> str:
    """Hash of what one target's texel samples depend on."""
    g = scene.geometry
    tri = target.triangles
    return content_hash("raster", target.name, tri, target.lightmap_uv, target.width, target.height,
                        g.positions[tri], g.normals[tri], int(texel_samples))


# --------------------------------------------------------------------------- file format
# A value is stored as a JSON tree whose arrays are members of a checksummed .npz
# (core.cache_files): nothing in a cache file can run code when it is read, and a
# damaged file is a miss. Dataclasses are rebuilt only from this package's modules.
_PACKAGE = __name__.rsplit(".", 1)[0]


def _encode(value, arrays: dict):
    """JSON-able tree for ``value``; arrays go into ``arrays`` under generated names."""
    if isinstance(value, np.ndarray):
        if value.dtype.hasobject:
            raise TypeError("object arrays are not stored")
        name = f"a{len(arrays)}"
        arrays[name] = value
        return {"array": name}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        cls = type(value)
        if not cls.__module__.startswith(_PACKAGE + "."):
            raise TypeError(f"dataclass {cls.__qualname__} is not from {_PACKAGE}")
        return {"dataclass": [cls.__module__[len(_PACKAGE) + 1:], cls.__qualname__],
                "fields": [[f.name, _encode(getattr(value, f.name), arrays)] for f in dataclasses.fields(value)]}
    if isinstance(value, (list, tuple)):
        return {"tuple" if isinstance(value, tuple) else "list": [_encode(v, arrays) for v in value]}
    if isinstance(value, dict):
        return {"dict": [[_encode(k, arrays), _encode(v, arrays)] for k, v in value.items()]}
    if isinstance(value, np.generic):
        return {"scalar": _encode(np.asarray(value), arrays)}
    if isinstance(value, slice):
        return {"slice": [_encode(v, arrays) for v in (value.start, value.stop, value.step)]}
    if value is None or isinstance(value, (bool, int, float, str)):
        return {"value": value}
    raise TypeError(f"cannot store a {type(value).__name__}")


def _decode(node, arrays: dict):
    if "array" in node:
        return arrays[node["array"]]
    if "dataclass" in node:
        module, qualname = node["dataclass"]
        cls = getattr(importlib.import_module(f"{_PACKAGE}.{module}"), qualname)
        if not dataclasses.is_dataclass(cls):
            raise TypeError(f"{qualname} is not a dataclass")
        values = {name: _decode(v, arrays) for name, v in node["fields"]}
        init = {f.name for f in dataclasses.fields(cls) if f.init}
        obj = cls(**{k: v for k, v in values.items() if k in init})
        for k, v in values.items():
            if k not in init:
                object.__setattr__(obj, k, v)
        return obj
    if "tuple" in node:
        return tuple(_decode(v, arrays) for v in node["tuple"])
    if "list" in node:
        return [_decode(v, arrays) for v in node["list"]]
    if "dict" in node:
        return {_decode(k, arrays): _decode(v, arrays) for k, v in node["dict"]}
    if "scalar" in node:
        return _decode(node["scalar"], arrays)[()]
    if "slice" in node:
        return slice(*(_decode(v, arrays) for v in node["slice"]))
    return node["value"]


DEFAULT_MAX_BYTES = 2 * 1024 ** 3
"""Disk budget of a bake cache folder (2 GiB: a few 4M-photon maps)."""


class BakeCache:
    """Content-keyed store of bake intermediates.

    Parameters
    ----------
    folder : directory for ``<kind>-<sha256>.npz`` files (created on first store), or None
        for memory only. Disk entries survive the process; memory entries live as long as
        the object. A 4M-photon map takes ~400 MB on disk. Each file carries a checksum; a
        damaged file is a miss (recomputed and rewritten), and a folder that cannot be
        written only costs the reuse.
    memory : keep entries in memory too (default True).

    Attributes
    ----------
    hits, misses, stores : dict kind -> count, for statistics and tests.
    warnings : list of str, messages for the user (e.g. the folder could not be written);
        each distinct message once.
    """

    def __init__(self, folder: os.PathLike | str | None = None, memory: bool = True):
        self.folder = Path(folder) if folder is not None else None
        self.memory = memory
        self._entries: dict = {}
        self.code = code_hash()
        self.hits = {k: 0 for k in KINDS}
        self.misses = {k: 0 for k in KINDS}
        self.stores = {k: 0 for k in KINDS}
        self.warnings: list[str] = []

    def _warn(self, message: str) -> None:
        if message not in self.warnings:
            self.warnings.append(message)

    def prune(self, max_bytes: int = DEFAULT_MAX_BYTES) -> int:
        """Delete the least recently written disk entries until the folder holds at most ``max_bytes``.

        Returns the number of files removed. A photon map can take hundreds of MB, so the
        add-on prunes after every bake rather than letting the folder grow without bound.
        """
        if self.folder is None or not self.folder.is_dir():
            return 0
        removed = 0
        try:
            for old in self.folder.glob("*.pkl"):  # format 1 (pickle): never read again
                old.unlink(missing_ok=True)
                removed += 1
            files = sorted(self.folder.glob("*.npz"), key=lambda f: f.stat().st_mtime, reverse=True)
            total = 0
            for f in files:
                size = f.stat().st_size
                if total + size > max_bytes:
                    f.unlink(missing_ok=True)
                    removed += 1
                else:
                    total += size
        except OSError as e:
            self._warn(f"bake cache folder {str(self.folder)!r} could not be pruned ({e.strerror or e})")
        return removed

    def key(self, kind: str, *parts) -> str:
        """The full key of an entry: kind, format version, code hash and ``parts``."""
        if kind not in KINDS:
            raise ValueError(f"BakeCache: unknown kind {kind!r}; expected one of {KINDS}")
        return content_hash(kind, FORMAT_VERSION, self.code, *parts)

    def _path(self, kind: str, key: str) -> Path:
        return self.folder / f"{kind}-{key}.npz"

    def get(self, kind: str, key: str):
        """The stored value, or None (counted as a hit or a miss)."""
        value = self._entries.get((kind, key)) if self.memory else None
        if value is None and self.folder is not None:
            value = self._read(kind, key)
            if value is not None and self.memory:
                self._entries[(kind, key)] = value
        if value is None:
            self.misses[kind] += 1
        else:
            self.hits[kind] += 1
        return value

    def put(self, kind: str, key: str, value) -> None:
        """Store ``value`` (in memory, and atomically on disk when a folder is set)."""
        self.stores[kind] += 1
        if self.memory:
            self._entries[(kind, key)] = value
        if self.folder is not None:
            self._write(kind, key, value)

    def _read(self, kind: str, key: str):
        """The value in the entry's file, or None (missing, damaged, foreign: a miss)."""
        entry = read_entry(self._path(kind, key))
        if entry is None:
            return None
        header, arrays = entry
        if header.get("kind") != kind or header.get("key") != key:
            return None
        try:
            return _decode(header["value"], arrays)
        except (KeyError, TypeError, ValueError, AttributeError, ImportError, IndexError):
            return None

    def _write(self, kind: str, key: str, value) -> None:
        arrays: dict = {}
        try:
            tree = _encode(value, arrays)
        except TypeError as e:  # a value this format cannot hold stays in memory only
            self._warn(f"bake cache: {kind} entries are not stored on disk ({e})")
            return
        try:
            write_entry(self._path(kind, key), {"kind": kind, "key": key, "value": tree}, arrays)
        except OSError as e:
            self._warn(f"bake cache folder {str(self.folder)!r} cannot be written ({e.strerror or e}); "
                       f"the bake goes on without caching")

    def memoise(self, kind: str, key: str, compute):
        """The stored value of ``kind``/``key``, or ``compute()``'s, stored (the bake's one memo step)."""
        value = self.get(kind, key)
        if value is None:
            value = compute()
            self.put(kind, key, value)
        return value

    def counters(self) -> dict:
        """Flat statistics: ``cache_hits_<kind>``, ``cache_misses_<kind>``."""
        out = {}
        for k in KINDS:
            out[f"cache_hits_{k}"] = self.hits[k]
            out[f"cache_misses_{k}"] = self.misses[k]
        return out

    def clear(self) -> None:
        """Forget the memory entries (files on disk stay)."""
        self._entries.clear()


class NoBakeCache:
    """Stands in for "no cache": computes everything, stores nothing, counts nothing (keys are empty)."""

    def key(self, kind: str, *parts) -> str:
        return ""

    def get(self, kind: str, key: str):
        return None

    def put(self, kind: str, key: str, value) -> None:
        pass

    def memoise(self, kind: str, key: str, compute):
        return compute()

    def counters(self) -> dict:
        return {}
