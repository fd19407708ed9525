"""A uniform grid over the records' zones of influence: which records may accept a point (Equation 2).

Record k accepts p only if ``|p - p_k| <= a R_k`` (its zone). The grid lists, per cell, every
record whose zone's bounding box overlaps the cell; a point's candidates are its cell's list,
tested against each zone exactly. That is a point-side lookup of fixed cost per point, built
once per cache: pass 3 shades hits scattered over the whole scene, where a record-side search
(one kd ball query per record that may reach the batch) paid for every record in every batch
(Sponza: 36k ball queries per batch of 75k hits, 1.6 us per hit; the grid 0.5 us).

Each point's records come out in ascending order, the order a record-side search listed them
in, so Equation 3's per-point sums are the same to the last bit.
"""
from __future__ import annotations

import threading

import numpy as np

from . import native_kernels
from .executor import row_chunks

CELL_PER_ZONE = 3.0
"""Cell side / the median zone radius; the pairs found do not depend on it. A bake builds about ten
grids (Equation 3 at texels and at holes, the hit grids) on one thread and queries them on all.
Sponza 16 texels/m, 78k records (pass 2 and holes) and 1.2M points: 2.0 builds in 0.47 s with
47 entries per record and looks up 0.78 us per point; 3.0 0.21 s, 19 entries, 0.98 us; 4.0 0.11 s,
1.40 us. On the 36k pass-2 records alone 1.0 was slower to build (38 entries: 0.41 s) for 0.48 us."""
DENSE_CELL_PER_ZONE = 1.0
"""The cell side where many points query each record (:func:`cell_per_zone`): a point's cell then
lists fewer records whose zones miss it, and the longer build is paid once for many points."""
DENSE_POINTS_PER_RECORD = 32.0
"""Points per record from which :func:`cell_per_zone` picks DENSE_CELL_PER_ZONE. Preview's texel
lookups reach 36-115 points per record on Sponza 16 texels/m (its 3.2 M samples of fine zones over
28k records: 9.3 -> 6.1 s at 1.0), Final's 0.0-25 (at 1.0 its lookups over 154k records for 45k
points took 3.5 s instead of 0.24 s to build)."""
MAX_ENTRIES_PER_RECORD = 4096
"""A zone wider than this many cells (a few huge R_k beside many small ones) coarsens the grid
instead: memory stays O(records) whatever the spread of R_k."""
MAX_CELLS_PER_AXIS = 1024
"""Zones all far smaller than the scene (or of zero size) cannot make the cell index overflow."""
DENSE_CELLS_PER_ENTRY = 4
"""A dense cell table (8 bytes per cell) is used while cells <= this x entries, else a sorted
table searched per point."""


class ZoneGrid:
    """Cells of side ``cell`` over the zones' bounding boxes; CSR lists of records per occupied cell.

    p : (K, 3) float64 record positions; zone : (K,) float64 zone radii (scene units, a R_k);
    cell_per_zone : the cell side in median zone radii (:func:`cell_per_zone`).
    Memory: 40 bytes per (record, cell) entry (~20 entries per record at CELL_PER_ZONE) and
    8 bytes per cell of the dense table.
    """

    def __init__(self, p: np.ndarray, zone: np.ndarray, cell_per_zone: float = CELL_PER_ZONE):
        p = np.asarray(p, np.float64)
        zone = np.asarray(zone, np.float64)
        K = len(p)
        self.empty = K == 0
        if self.empty:
            return
        self.origin = (p - zone[:, None]).min(axis=0)
        extent = float(((p + zone[:, None]).max(axis=0) - self.origin).max())
        cell = max(cell_per_zone * float(np.median(zone)),
                   2.0 * float(zone.max()) / (MAX_ENTRIES_PER_RECORD ** (1 / 3) - 1.0),
                   extent / MAX_CELLS_PER_AXIS, 1e-30)
        self.cell = cell
        lo = np.floor((p - zone[:, None] - self.origin) / cell).astype(np.int64)
        hi = np.floor((p + zone[:, None] - self.origin) / cell).astype(np.int64)
        self.dims = hi.max(axis=0) + 1
        span = hi - lo + 1
        counts = span.prod(axis=1)
        record = np.repeat(np.arange(K, dtype=np.int64), counts)
        starts = np.cumsum(counts) - counts
        key = np.empty(len(record), np.int64)
        for rows in row_chunks(len(record)):  # millions of entries: passes whose temporaries the allocator reuses
            r = record[rows]
            # Offset of each entry inside its record's box, unravelled over the box's span.
            local = np.arange(rows.start, rows.stop, dtype=np.int64) - starts[r]
            sx, sy = span[r, 0], span[r, 1]
            key[rows] = self._key(lo[r, 0] + local % sx, lo[r, 1] + (local // sx) % sy, lo[r, 2] + local // (sx * sy))
        order = np.argsort(key, kind="stable")  # stable: records ascend within a cell
        key = key[order]
        self.records = record[order]
        # Each entry carries its record's centre and squared zone: the lookup reads them in runs.
        self.entry_p = np.take(p, self.records, axis=0)
        self.entry_zone2 = (zone * zone)[self.records]
        self.entries = len(key)
        n_cells = int(self.dims.prod())
        if n_cells <= DENSE_CELLS_PER_ENTRY * max(self.entries, 1):
            # A dense table of every cell's first entry: one read per point instead of a binary search.
            self.first = np.zeros(n_cells + 1, np.int64)
            np.cumsum(np.bincount(key, minlength=n_cells), out=self.first[1:])
            self.cells = None
        else:
            self.cells, self.start = np.unique(key, return_index=True)
            self.stop = np.append(self.start[1:], len(key))

    def _key(self, ix, iy, iz):
        return (iz * self.dims[1] + iy) * self.dims[0] + ix

    def pairs(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rows, records) int64: every (point, record) with ``|q - p_k| <= zone_k``, points ascending,
        each point's records ascending. q : (m, 3) float64."""
        if self.empty or len(q) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        lib = native_kernels.library()
        return self.pairs_numpy(q) if lib is None else native_kernels.zone_pairs(lib, self, q)

    def pairs_numpy(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`pairs` in numpy (the fallback of :mod:`core.native_kernels`, and its reference)."""
        if self.empty or len(q) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        # Non-finite or far-away points land outside the grid (-1) before the integer cast.
        c = np.nan_to_num(np.floor((q - self.origin) / self.cell), nan=-1.0, posinf=-1.0, neginf=-1.0)
        c = np.clip(c, -1.0, self.dims.astype(np.float64)).astype(np.int64)
        inside = np.flatnonzero(np.all((c >= 0) & (c < self.dims), axis=1))
        key = self._key(c[inside, 0], c[inside, 1], c[inside, 2])
        if self.cells is None:
            start, count = self.first[key], self.first[key + 1] - self.first[key]
            rows_in = inside
        else:
            slot = np.minimum(np.searchsorted(self.cells, key), len(self.cells) - 1)
            found = self.cells[slot] == key
            rows_in, slot = inside[found], slot[found]
            start, count = self.start[slot], self.stop[slot] - self.start[slot]
        entry = np.arange(int(count.sum()), dtype=np.int64) + np.repeat(start - (np.cumsum(count) - count), count)
        rows = np.repeat(rows_in, count)
        d = np.take(q, rows, axis=0) - np.take(self.entry_p, entry, axis=0)
        # Summed in cKDTree's order (x, y, z), so the boundary decisions match a kd-tree ball query.
        d2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
        keep = np.flatnonzero(d2 <= self.entry_zone2[entry])
        return rows[keep], self.records[entry[keep]]


def cell_per_zone(points: int, records: int) -> float:
    """The cell side, in median zone radii, for a grid over ``records`` zones that ``points`` points will
    query: finer where each record meets many points (DENSE_POINTS_PER_RECORD)."""
    return DENSE_CELL_PER_ZONE if points >= DENSE_POINTS_PER_RECORD * max(records, 1) else CELL_PER_ZONE


MORTON_BITS = 10
"""Bits per axis of :func:`spatial_order`'s Morton key: 1024 steps across the points' box."""


def spatial_order(p: np.ndarray) -> np.ndarray:
    """(m,) int64 permutation putting points p (m, 3) in Morton (Z-curve) order.

    Queries in that order walk a kd-tree or a grid along neighbouring nodes: pass 3's gathering
    hits come in ray order, scattered over the scene, and Sponza's nearest-photon queries on them
    ran 2.5x faster sorted (identical answers).
    """
    if len(p) == 0:
        return np.zeros(0, np.int64)
    lib = native_kernels.library()
    if lib is not None and MORTON_BITS == native_kernels.MORTON_BITS:  # compiled: the keys and a radix sort
        return native_kernels.morton_order(lib, p)
    return np.argsort(morton_keys_numpy(p), kind="stable")


def morton_keys_numpy(p: np.ndarray) -> np.ndarray:
    """(m,) uint64 Morton keys of points p (m, 3) over their bounding box, MORTON_BITS per axis (the compiled
    kernel's reference, :func:`core.native_kernels.morton_keys`: one pass for the box, one for the keys)."""
    p = np.asarray(p, np.float64)
    if len(p) == 0:
        return np.zeros(0, np.uint64)
    with np.errstate(invalid="ignore"):  # a NaN or infinite point: the box's extent too, every key 0
        lo, hi = p.min(axis=0), p.max(axis=0)
        scale = (2 ** MORTON_BITS - 1) / max(float((hi - lo).max()), 1e-300)
        c = np.nan_to_num((p - lo) * scale, nan=0.0, posinf=0.0, neginf=0.0)
    c = np.clip(c, 0, 2 ** MORTON_BITS - 1).astype(np.uint64)
    return _spread_bits(c[:, 0]) | (_spread_bits(c[:, 1]) << np.uint64(1)) | (_spread_bits(c[:, 2]) << np.uint64(2))


def _spread_bits(x: np.ndarray) -> np.ndarray:
    """Insert two zero bits between each of the low 10 bits of x (uint64)."""
    x = x & np.uint64(0x3FF)
    x = (x | (x << np.uint64(16))) & np.uint64(0x030000FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x0300F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x030C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x09249249)
    return x


class JoinedZoneGrid:
    """The pairs of several zone grids over consecutive runs of one cache's records, as one grid over all
    of them would list them: ``parts`` are (grid, offset), the grid's record r being the cache's offset + r,
    each part's records after the previous part's. A point's pairs from the first part come first, so its
    records still ascend and Equation 3 sums the same terms in the same order, to the last bit."""

    def __init__(self, parts: list):
        self.parts = parts

    def pairs(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        found = [(rows, records + offset) for grid, offset in self.parts for rows, records in [grid.pairs(q)]]
        return merge_pairs(found, len(q))


def merge_pairs(parts: list, m: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, records) of ``parts`` [(rows, records), ...] interleaved by point: rows ascending and, per
    point, the first part's records, then the second's, ... (each part's rows ascending). m : points."""
    counts = [np.bincount(rows, minlength=m) for rows, _ in parts]
    total = np.sum(counts, axis=0) if counts else np.zeros(m, np.int64)
    row_start = np.cumsum(total) - total
    out_rows, out_records = np.empty(int(total.sum()), np.int64), np.empty(int(total.sum()), np.int64)
    before = np.zeros(m, np.int64)  # per point, entries of earlier parts
    for (rows, records), count in zip(parts, counts):
        within = np.arange(len(rows), dtype=np.int64) - np.repeat(np.cumsum(count) - count, count)
        at = row_start[rows] + before[rows] + within
        out_rows[at], out_records[at] = rows, records
        before += count
    return out_rows, out_records


class SharedZones:
    """What every target's lookups in one bake share over the cache they all start from (pass 3's records),
    built once instead of once per target and lookup: the zone grid, and the kd-tree neighbour clamping
    places hole records against (:meth:`clamp_level`). A lookup over that cache takes the grid as it is;
    one over the cache with records appended (a target's hole records, :meth:`IrradianceCache.extend`)
    joins it with a grid over the appended ones (:class:`JoinedZoneGrid`). A scene of 300 props built 1,181
    grids over its 47k records, 13 of its 58 s. The pairs, and so E, are those of a grid over the whole cache.

    p, R : (K, 3) the shared records' positions and (K,) radii R_k; a : Ward's a (zones a R_k)."""

    def __init__(self, p: np.ndarray, R: np.ndarray, a: float):
        self.p, self.R = p, np.asarray(R, np.float64)
        self.zone = a * self.R  # as CacheLookup.own_zone: the same floats
        self._grid, self._clamp = None, None
        self._lock = threading.Lock()

    def __getstate__(self):  # a Dask worker gets the lookups that carry it: not the lock
        return {k: v for k, v in self.__dict__.items() if k != "_lock"}

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._lock = threading.Lock()

    def starts(self, p: np.ndarray, values: np.ndarray, shared_values: np.ndarray) -> bool:
        """Whether records p (K', 3) with ``values`` (K',) begin with the shared ones (``shared_values``)."""
        K = len(self.p)
        return len(p) >= K and np.array_equal(p[:K], self.p) and np.array_equal(values[:K], shared_values)

    def grid(self, p: np.ndarray, zone: np.ndarray, cell_per_zone: float = CELL_PER_ZONE):
        """A grid over records p (K', 3) of zones (K',): the shared one joined with one over those past it
        where the shared records are their first K (equal positions and zones), else a grid of their own.
        The shared grid takes the first caller's cell_per_zone (a speed choice only)."""
        if not self.starts(p, zone, self.zone):
            return ZoneGrid(p, zone, cell_per_zone)
        K = len(self.p)
        with self._lock:
            if self._grid is None:
                self._grid = ZoneGrid(self.p, self.zone, cell_per_zone)
        if len(p) == K:
            return self._grid
        return JoinedZoneGrid([(self._grid, 0), (ZoneGrid(p[K:], zone[K:], cell_per_zone), K)])

    def clamp_level(self) -> tuple:
        """(p, R, cKDTree over p) of the shared records: neighbour clamping's first level."""
        from scipy.spatial import cKDTree

        with self._lock:
            if self._clamp is None:
                self._clamp = (self.p, self.R, cKDTree(self.p))
        return self._clamp
