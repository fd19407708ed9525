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
``photons``     light transport + ``photons``, photon bounces, ``seed``
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
import os
import pickle
import tempfile
from pathlib import Path

import numpy as np

FORMAT_VERSION = 1
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
    return content_hash("transport", g.positions, g.normals, g.uvs, g.material, scene.materials,
                        scene.textures, scene.lights, scene.world, *transmissive)


def target_key(scene, target, texel_samples: int) -> str:
    """Hash of what one target's texel samples depend on."""
    g = scene.geometry
    tri = target.triangles
    return content_hash("raster", target.name, tri, target.lightmap_uv, target.width, target.height,
                        g.positions[tri], g.normals[tri], int(texel_samples))


DEFAULT_MAX_BYTES = 2 * 1024 ** 3
"""Disk budget of a bake cache folder (2 GiB: a few 4M-photon maps)."""


class BakeCache:
    """Content-keyed store of bake intermediates.

    Parameters
    ----------
    folder : directory for ``<kind>-<sha256>.pkl`` files (created on first store), or None
        for memory only. Disk entries survive the process; memory entries live as long as
        the object. A 4M-photon map takes ~400 MB on disk.
    memory : keep entries in memory too (default True).

    Attributes
    ----------
    hits, misses, stores : dict kind -> count, for statistics and tests.
    """

    def __init__(self, folder: os.PathLike | str | None = None, memory: bool = True):
        self.folder = Path(folder) if folder is not None else None
        self.memory = memory
        self._entries: dict = {}
        self.code = code_hash()
        self.hits = {k: 0 for k in KINDS}
        self.misses = {k: 0 for k in KINDS}
        self.stores = {k: 0 for k in KINDS}

    def prune(self, max_bytes: int = DEFAULT_MAX_BYTES) -> int:
        """Delete the least recently written disk entries until the folder holds at most ``max_bytes``.

        Returns the number of files removed. A photon map can take hundreds of MB, so the
        add-on prunes after every bake rather than letting the folder grow without bound.
        """
        if self.folder is None or not self.folder.is_dir():
            return 0
        files = sorted(self.folder.glob("*.pkl"), key=lambda f: f.stat().st_mtime, reverse=True)
        total, removed = 0, 0
        for f in files:
            size = f.stat().st_size
            if total + size > max_bytes:
                f.unlink(missing_ok=True)
                removed += 1
            else:
                total += size
        return removed

    def key(self, kind: str, *parts) -> str:
        """The full key of an entry: kind, format version, code hash and ``parts``."""
        if kind not in KINDS:
            raise ValueError(f"BakeCache: unknown kind {kind!r}; expected one of {KINDS}")
        return content_hash(kind, FORMAT_VERSION, self.code, *parts)

    def _path(self, kind: str, key: str) -> Path:
        return self.folder / f"{kind}-{key}.pkl"

    def get(self, kind: str, key: str):
        """The stored value, or None (counted as a hit or a miss)."""
        value = self._entries.get((kind, key)) if self.memory else None
        if value is None and self.folder is not None:
            path = self._path(kind, key)
            if path.is_file():
                try:
                    with open(path, "rb") as f:
                        value = pickle.load(f)
                except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError):
                    value = None  # a damaged or foreign file is a miss, rewritten on store
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
            self.folder.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{kind}-", suffix=".pkl", dir=self.folder)
            try:
                with os.fdopen(fd, "wb") as f:
                    pickle.dump(value, f, protocol=pickle.HIGHEST_PROTOCOL)
                os.replace(tmp, self._path(kind, key))
            except BaseException:
                if os.path.exists(tmp):
                    os.unlink(tmp)
                raise

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

    def memoise(self, kind: str, key: str, compute):
        return compute()

    def counters(self) -> dict:
        return {}
