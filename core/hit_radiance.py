"""Irradiance at pass 3's gathering hits, read from a grid over every triangle (deviation: hit-grid).

docs/DEVIATIONS.md, switch ``Deviations.hit_grid``. A real ray's radiance is albedo x
(E_direct + E_indirect) / pi at its hit (:mod:`core.real_rays`). Computed per hit, that costs a
record lookup, a nearest-photon fallback and a shadow ray per light: ~4.5 us per hit in numpy
against ~0.3 us for the ray itself, and Sponza's Final bake at 16 texels/m shades ~33 M hits.
Irradiance over a surface changes on the scale of the cache's records, so it is computed once per
cell of a grid over each triangle (L^2 similar sub-triangles, L ~ the longest edge /
(HIT_GRID_SPACING x R_min)), at the cell's centroid and on both sides. A hit that sees its cell's
centroid reads the cell (one occlusion ray: a triangle may run under a thin wall, and the cell's
far side must not light the near one); a hit that does not is shaded on its own. Centroids, not
grid vertices: a vertex on a triangle's edge sits where a neighbouring surface meets it (Sponza at
4 texels/m: indirect bias -2.3 % from vertices, -1.7 % from centroids, -1.5 % per hit). A hit that
reads its cell also takes the cell's mean albedo (four texture samples, :func:`cell_albedo`): with E
constant over the cell, albedo x E averaged over the hits that land there is that mean x E, so the
gathered radiance keeps its expectation and loses the texture's variance within the cell, and the
texture is sampled once per cell instead of per hit (Sponza 16 texels/m: 33 M hits).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .albedo import albedo as albedo_at
from .constants import (HIT_GRID_DIRECT_SAMPLES, HIT_GRID_MAX_CELLS, HIT_GRID_MAX_SIDE,
                        HIT_GRID_SPACING, HIT_GRID_CELLS_PER_HIT, OPEN_CELL_REACH)
from .direct import shade_direct
from .executor import TEXEL_CHUNK, slices


CELL = np.dtype({"names": ["centroid", "albedo", "open"], "formats": [("<f8", (3,)), ("<f4", (3,)), ("?", (2,))],
                 "offsets": [0, 24, 36], "itemsize": 64})
"""One row of :attr:`HitGrid.cells`: a cell's centroid, mean albedo and openness on both sides in one 64-byte
cache line (core/native/pdic_native.c reads it as ``PdicCell``)."""


@dataclass(frozen=True)
class HitGrid:
    """E over the cells of a grid on each triangle, on both of its sides (constant per cell).

    side : (T,) int64 L, grid steps along each edge of the triangle (>= 1): L^2 cells, in rows of
        constant v, row j holding its lower cells (i, j) at 2i and upper cells at 2i + 1 from j (2L - j);
    offset : (T,) int64 the triangle's first cell;
    E : (2, V, 3) float32 irradiance W/m^2 at the cells' centroids, on the side the face normal points
        to [0] and the other [1]; E_direct : (2, V, 3) float32 its direct part (a later grid over the
        same cells reuses it); centroid : (V, 3) float64 the cells' centroids (a hit's cell is found
        per hit, its centroid read); albedo : (V, 3) float32 the cells' mean albedo, or None (hits then
        take their own); fallback : (2, V) int32 the nearest-photon fallback's pick at each centroid and
        side (:func:`~core.photon_fallback.nearest_photon_seen`, NOT_ASKED where a record accepted it),
        which a later grid over the same cells reuses; open : (2, V) bool, on each side, whether the
        cell's centroid sees the cell's three corners (each pulled OPEN_CELL_REACH of the way in), or
        None (deviation: open-cells).
    cells : (V,) :data:`CELL` the centroids, albedos and openness in one table, 64-byte aligned (copied to
        a boundary when unpickled); ``centroid``, ``albedo`` and ``open`` are views of it. Hits read their
        cells at random (Sponza 16/m: 107 M hits over 2.35 M cells); one cache line a cell instead of three
        halves that read (:func:`core.native_kernels.hit_cells`: 8.0-8.6 -> 4.3-5.0 CPU s a bake). Given (a
        later grid over the same cells), it is used as it is where the three arrays are its views, else
        built anew.
    Memory: 120 bytes per cell once built (a later grid sharing the table and E_direct: 32 more), and the three
    arrays given beside the table while it is built; V <= HIT_GRID_MAX_CELLS.
    """

    side: np.ndarray
    offset: np.ndarray
    E: np.ndarray
    E_direct: np.ndarray
    centroid: np.ndarray
    albedo: np.ndarray | None = None
    fallback: np.ndarray | None = None
    open: np.ndarray | None = None
    cells: np.ndarray | None = field(default=None, repr=False, compare=False)

    def __post_init__(self):
        cells = self.cells
        if cells is None or not _views_of(cells, self.centroid, self.albedo, self.open):
            cells = cell_table(self.centroid, self.albedo, self.open)
        self._share(cells, self.albedo is not None, self.open is not None)

    def _share(self, cells: np.ndarray, albedo: bool, open_: bool) -> None:
        object.__setattr__(self, "cells", cells)
        object.__setattr__(self, "centroid", cells["centroid"])
        object.__setattr__(self, "albedo", cells["albedo"] if albedo else None)
        object.__setattr__(self, "open", cells["open"].T if open_ else None)

    def __getstate__(self) -> dict:
        """The table once, not its views as copies of their own (a Dask worker receives the grid)."""
        state = dict(self.__dict__)
        for name in ("centroid", "albedo", "open"):
            state[name] = state[name] is not None
        return state

    def __setstate__(self, state: dict) -> None:
        for name, value in state.items():
            if name not in ("centroid", "albedo", "open"):
                object.__setattr__(self, name, value)
        self._share(aligned_cells(state["cells"]), state["albedo"], state["open"])

    def lookup(self, triangle: np.ndarray, barycentric: np.ndarray, back: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
        """(E (h, 3) float64 of each hit's cell, the cell's centroid (h, 3), its albedo (h, 3) float64 or
        None, whether the cell is open on the side met (h,) bool: a hit there sees the centroid without
        an occlusion ray of its own) at hits: triangle (h,) int64, Embree barycentric (h, 2), back (h,)
        bool (the ray reached the side the face normal points away from)."""
        L = self.side[triangle]
        u = np.clip(barycentric[:, 0], 0.0, 1.0)
        v = np.clip(barycentric[:, 1], 0.0, 1.0)
        x, y = u * L, v * L
        i = np.clip(np.floor(x), 0, L - 1).astype(np.int64)
        j = np.clip(np.floor(y), 0, L - 1).astype(np.int64)
        i = np.minimum(i, L - 1 - j)  # a hit on the far edge (u + v = 1) rounds into the row's last cell
        # The upper cell of (i, j), if the row has one there (a hit just past u + v = 1 by rounding must not
        # read the next row's, or past the top row, the next triangle's first cell).
        upper = ((x - i) + (y - j) > 1.0) & (i < L - 1 - j)
        cell = self.offset[triangle] + j * (2 * L - j) + 2 * i + upper
        E = np.take(self.E.reshape(-1, 3), back * self.E.shape[1] + cell, axis=0).astype(np.float64)
        rho = None if self.albedo is None else np.take(self.albedo, cell, axis=0).astype(np.float64)
        is_open = np.zeros(len(cell), bool) if self.open is None else self.open[back.astype(np.int64), cell]
        return E, np.take(self.centroid, cell, axis=0), rho, is_open


def cell_table(centroid: np.ndarray, albedo: np.ndarray | None, open_: np.ndarray | None) -> np.ndarray:
    """(V,) :data:`CELL` rows of centroids (V, 3), albedos (V, 3) (zero where None) and openness (2, V) (False where
    None), starting on a 64-byte boundary so that each row is one cache line."""
    table = _empty_cells(len(centroid))
    table["centroid"] = centroid
    if albedo is not None:
        table["albedo"] = albedo
    if open_ is not None:
        table["open"] = np.asarray(open_).T
    return table


def aligned_cells(cells: np.ndarray) -> np.ndarray:
    """``cells`` if its rows start on 64-byte boundaries, else a copy that does (an unpickled table lies where
    the allocator put it: the kernel would read two lines a row, and doubles off their alignment)."""
    if cells.ctypes.data % 64 == 0 and cells.flags.c_contiguous:
        return cells
    table = _empty_cells(len(cells))
    table[...] = cells
    return table


def _empty_cells(V: int) -> np.ndarray:
    """(V,) :data:`CELL` rows of zeros (the padding too, so that a table's bytes depend on its cells alone: Dask
    keys arrays by content), the first on a 64-byte boundary."""
    # np.empty, then zeros: numpy asks Linux for huge pages for large empty arrays, not for zeroed ones (calloc).
    buffer = np.empty(V * CELL.itemsize + 64, np.uint8)
    buffer[:] = 0
    start = (-buffer.ctypes.data) % 64
    return buffer[start:start + V * CELL.itemsize].view(CELL)


def _views_of(cells: np.ndarray, centroid: np.ndarray, albedo: np.ndarray | None, open_: np.ndarray | None) -> bool:
    """Are ``centroid``, ``albedo`` and ``open_`` (those not None) the views of ``cells`` that HitGrid keeps?"""
    def same(a, b):
        return (a.__array_interface__["data"][0] == b.__array_interface__["data"][0] and a.shape == b.shape
                and a.strides == b.strides and a.dtype == b.dtype)

    return (cells.dtype == CELL and same(centroid, cells["centroid"])
            and (albedo is None or same(albedo, cells["albedo"])) and (open_ is None or same(open_, cells["open"].T)))


def _centroids(positions: np.ndarray, triangle: np.ndarray, i: np.ndarray, j: np.ndarray, upper: np.ndarray,
               L: np.ndarray) -> np.ndarray:
    """(n, 3) world centroids of cells (i, j, upper) of side-L grids on their triangles: a lower cell's
    at barycentric ((i + 1/3) / L, (j + 1/3) / L), an upper cell's at ((i + 2/3) / L, (j + 2/3) / L)."""
    third = np.where(upper, 2 / 3, 1 / 3)
    corners = np.take(positions, triangle, axis=0)  # np.take: a fraction of fancy indexing's cost
    return _at_grid_steps(corners, i + third, j + third, L)


def _at_grid_steps(corners: np.ndarray, x: np.ndarray, y: np.ndarray, L: np.ndarray) -> np.ndarray:
    """(n, 3) world points at (x, y) grid steps (n,) of side-L grids (n,) on triangles ``corners`` (n, 3, 3):
    barycentric (x / L, y / L), the weights of corners 1 and 2."""
    p0 = corners[:, 0]
    return p0 + (x / L)[:, None] * (corners[:, 1] - p0) + (y / L)[:, None] * (corners[:, 2] - p0)


def grid_sides(positions: np.ndarray, spacing: float, budget: int) -> np.ndarray:
    """(T,) int64 L per triangle: its longest edge / spacing, in [1, HIT_GRID_MAX_SIDE], the spacing
    widened until the grid holds at most ``budget`` cells (or one per triangle)."""
    edges = np.stack([positions[:, 1] - positions[:, 0], positions[:, 2] - positions[:, 1],
                      positions[:, 0] - positions[:, 2]], axis=1)
    longest = np.linalg.norm(edges, axis=2).max(axis=1)
    spacing = max(float(spacing), 1e-30)
    while True:
        L = np.clip(np.ceil(longest / spacing), 1, HIT_GRID_MAX_SIDE).astype(np.int64)
        if int((L * L).sum()) <= budget or L.max() == 1:
            return L
        spacing *= 1.25


def grid_points(positions: np.ndarray, L: np.ndarray, map=map) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(offset (T,), triangle of each cell (V,), the cells' centroids in world space (V, 3)).

    Centroids lie inside their triangle, off its edges: none sits where another surface meets the
    triangle (a shadow ray from there would start inside the neighbour).
    map : runs chunks of cells (an executor's ``map`` spreads them over threads; the centroids are the same)."""
    offset, triangle = cell_triangles(L)

    def centroids(s: slice) -> np.ndarray:
        t = triangle[s]
        i, j, upper = grid_cells(L, offset, t, s.start)
        return _centroids(positions, t, i, j, upper, L[t])

    parts = list(map(centroids, slices(len(triangle), GRID_POINTS_CHUNK))) or [np.zeros((0, 3))]
    return offset, triangle, np.concatenate(parts)


GRID_POINTS_CHUNK = 8 * TEXEL_CHUNK
"""Cells whose centroids one task computes (Sponza 16 texels/m: 2.3 M cells, 1 s on one thread)."""


def cell_triangles(L: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(offset (T,) each triangle's first cell, triangle (V,) of each cell) of grids of sides L (T,)."""
    counts = L * L
    return np.cumsum(counts) - counts, np.repeat(np.arange(len(L), dtype=np.int64), counts)


def grid_cells(L: np.ndarray, offset: np.ndarray, triangle: np.ndarray, first: int = 0
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(i, j, upper) of cells ``first``, ``first`` + 1, ... (triangle (n,) their triangles) of grids of
    sides L (T,) laid out from ``offset``: the inverse of :meth:`HitGrid.lookup`'s cell index."""
    Lc = L[triangle]
    k = np.arange(first, first + len(triangle), dtype=np.int64) - offset[triangle]
    # Row j starts at j (2L - j) = L^2 - (L - j)^2: invert, then fix the square root's rounding.
    j = np.floor(Lc - np.sqrt(np.maximum(Lc * Lc - k, 0))).astype(np.int64)
    j = np.where(j * (2 * Lc - j) > k, j - 1, j)
    j = np.where((j + 1) * (2 * Lc - j - 1) <= k, j + 1, j)
    rest = k - j * (2 * Lc - j)
    return rest // 2, j, rest % 2 == 1


def open_cells(positions: np.ndarray, caster, L: np.ndarray, offset: np.ndarray, triangle: np.ndarray,
               centroid: np.ndarray, executor, progress) -> np.ndarray:
    """(2, V) bool: on the side the face normal points to [0] and the other [1], does each cell's
    centroid see its three corners, each pulled OPEN_CELL_REACH of the way toward the centroid (both ends
    lifted off the surface, as a hit's occlusion ray to the centroid is; deviation: open-cells)?

    A surface that separates part of a cell from its centroid (a wall standing on the triangle, a solid
    the triangle runs into) crosses the cell: a line across a triangle leaves a corner on each side, so
    one of the three segments meets it. Pulled in, the corners stay off the triangle's edges, where a
    neighbouring surface meets it and would stop every segment at its end.
    """
    out = np.ones((2, len(triangle)), bool)

    def test(index, s):
        view = caster.serial()  # the executor runs this chunk: trace on its thread
        c, m, t = centroid[s], s.stop - s.start, triangle[s]
        i, j, upper = grid_cells(L, offset, t, s.start)
        # Per chunk: the cells' triangles' corners and normals would be 96 bytes per cell at once.
        corners, Lc = np.take(positions, t, axis=0), L[t].astype(np.float64)
        normal = caster.face_normals[t].astype(np.float64)
        # A lower cell's corners are (i, j), (i + 1, j), (i, j + 1) in grid steps; an upper cell's
        # (i + 1, j + 1), (i, j + 1), (i + 1, j).
        steps = np.where(upper[:, None, None], [[1, 1], [0, 1], [1, 0]], [[0, 0], [1, 0], [0, 1]])
        points = []
        for k in range(3):
            corner = _at_grid_steps(corners, i + steps[:, k, 0], j + steps[:, k, 1], Lc)
            points.append(c + OPEN_CELL_REACH * (corner - c))
        n = np.concatenate([normal, -normal] * 3)  # (corner, side) blocks of m
        seen = view.sides_visible(np.tile(c, (6, 1)), n, np.repeat(np.stack(points), 2, axis=0).reshape(-1, 3), n)
        return seen.reshape(3, 2, m).all(axis=0)

    chunks = slices(len(triangle), TEXEL_CHUNK)
    for s, part in zip(chunks, executor.map_chunks(test, chunks, progress)):
        out[:, s] = part
    return out


def cell_albedo(scene, L: np.ndarray, offset: np.ndarray, triangle: np.ndarray, executor, progress) -> np.ndarray:
    """(V, 3) float32 mean albedo over each cell at four points, the centroids of its four half-size
    sub-triangles (the cell's centroid and the three half way from it to its corners).

    Exact where the albedo is constant over the triangle (the mean of four equal float32 values).
    """
    # Corner offsets from the centroid in grid steps: lower cell (-1/3,-1/3), (2/3,-1/3), (-1/3,2/3);
    # upper cell the negatives. The sub-triangles' centroids lie half way from the centroid to each.
    steps = ((0.0, 0.0), (-1 / 6, -1 / 6), (1 / 3, -1 / 6), (-1 / 6, 1 / 3))
    out = np.zeros((len(triangle), 3), np.float64)

    def mean(index, s):
        t = triangle[s]
        i, j, upper = grid_cells(L, offset, t, s.start)
        Lc = L[t].astype(np.float64)
        third = np.where(upper, 2 / 3, 1 / 3)
        sign = np.where(upper, -1.0, 1.0)
        part = np.zeros((s.stop - s.start, 3), np.float64)
        for du, dv in steps:
            uv = np.stack([(i + third + sign * du) / Lc, (j + third + sign * dv) / Lc], axis=1)
            part += albedo_at(scene, t, uv)
        return part / len(steps)

    chunks = slices(len(triangle), TEXEL_CHUNK)
    for s, part in zip(chunks, executor.map_chunks(mean, chunks, progress)):
        out[s] = part
    return out.astype(np.float32)


def build_hit_grid(scene, caster, indirect_at, R_min: float, hits: int, seed: int, stream, executor, progress,
                   direct_from: HitGrid | None = None, with_open_cells: bool = False, light_budget: bool = False
                   ) -> tuple[HitGrid, dict]:
    """The grid over ``scene``'s triangles and counters (cells, shadow rays, the lookups' rays).

    indirect_at : callable (q (m, 3), n (m, 3), known (2, m) or None) -> (E_indirect on the side n faces
        (m, 3), on the other (m, 3), rays cast (the records' visibility test, the fallback), fallback
        picks (2, m)): what a hit would read there, reusing
        an earlier grid's fallback picks ``known`` (:func:`~core.real_rays.indirect_on_both_sides`).
    hits : about how many hits will read the grid; it gets at most HIT_GRID_CELLS_PER_HIT of that
        in cells (both sides counted), so it costs a fraction of the hits it replaces.
    stream : the random stream of the centroids' shadow rays (core/constants.py).
    direct_from : an earlier grid of this scene; its direct light, fallback picks and open cells are
        reused if its cells are the same.
    with_open_cells : find the cells open on each side (:func:`open_cells`; deviation: open-cells).
    light_budget : the centroids' soft lamps share their shadow rays (deviation: light-budget,
        :mod:`core.light_budget`).
    """
    positions = scene.geometry.positions
    budget = int(min(HIT_GRID_MAX_CELLS, HIT_GRID_CELLS_PER_HIT * hits / 2))
    L = grid_sides(positions, HIT_GRID_SPACING * R_min, budget)
    reuse = direct_from is not None and np.array_equal(direct_from.side, L)
    if reuse:  # the same cells: their centroids too
        (offset, triangle), q = cell_triangles(L), direct_from.centroid
    else:
        offset, triangle, q = grid_points(positions, L, executor.map)
    normal = caster.face_normals[triangle].astype(np.float64)
    E = np.zeros((2, len(q), 3), np.float32)
    E_direct = direct_from.E_direct if reuse else np.zeros((2, len(q), 3), np.float32)
    counters = {"hit_grid_cells": len(q), "hit_grid_shadow_rays": 0, "hit_grid_lookup_rays": 0, "hit_grid_open_rays": 0}
    opened = None
    if with_open_cells:
        if reuse and direct_from.open is not None:
            opened = direct_from.open
        else:
            opened = open_cells(positions, caster, L, offset, triangle, q, executor, progress)
            counters["hit_grid_open_rays"] = 6 * len(q)
    albedo = direct_from.albedo if reuse else cell_albedo(scene, L, offset, triangle, executor, progress)
    for side, n in enumerate((normal, -normal)):
        if not reuse:
            E_direct[side], direct_counters = shade_direct(scene, caster, q, n, n, HIT_GRID_DIRECT_SAMPLES, seed,
                                                           [*np.atleast_1d(stream).tolist(), side], executor,
                                                           progress, budget=light_budget)
            counters["hit_grid_shadow_rays"] += direct_counters["shadow_rays"]
    known = direct_from.fallback if reuse else None
    # Both sides in one pass: a centroid's nearest photons are the same on either side.
    parts = executor.map_chunks(lambda index, s: indirect_at(q[s], normal[s], None if known is None else known[:, s]),
                                slices(len(q), TEXEL_CHUNK), progress)
    for side in (0, 1):
        E_indirect = np.concatenate([part[side] for part in parts]) if parts else np.zeros((0, 3))
        E[side] = E_direct[side] + E_indirect
    counters["hit_grid_lookup_rays"] += sum(part[2] for part in parts)
    fallback = np.concatenate([part[3] for part in parts], axis=1).astype(np.int32) if parts else None
    return HitGrid(L, offset, E, E_direct, q, albedo, fallback, opened, direct_from.cells if reuse else None), counters
