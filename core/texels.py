"""Texel sample points in the world: rasterised light-map samples lifted onto the surface.

A :class:`TexelPoints` gathers the rasterised samples of every bake target into
one struct of arrays, so every later stage (direct light, cache lookups, hole
records) works on one flat batch regardless of how many objects are baked.
Memory: 8*3*2 + 4*3 + 8 + 4 + 4 + 4 = 80 bytes per sample.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .constants import DIRECT_FOOTPRINT_SIDE
from .crease_folding import off_centre_triangle, straddling_texels
from .executor import group_chunks, row_chunks
from .raster import (RasterMasks, checked_uv, footprint_points, on_centre_triangles, rasterize_rows, row_bands,
                     with_centre_footprints)
from .scene import Scene
from .vectors import norms


@dataclass(frozen=True)
class TexelPoints:
    """All texel sample points of all targets (n samples).

    p : (n, 3) float64 scene-local positions.
    n_shading : (n, 3) float64 unit interpolated shading normals (front side).
    n_geometric : (n, 3) float64 unit geometric normals of the sample's triangle.
    triangle : (n,) int64 global triangle index (into Geometry).
    barycentric : (n, 2) float64 Embree-style (u, v) of the sample in its triangle.
    target : (n,) int32 bake-target index.
    texel : (n,) int64 flat texel index y*width+x within its target's image.
    weight : (n,) float32 the sample's share of its texel (a texel's weights sum to 1).
    """

    p: np.ndarray
    n_shading: np.ndarray
    n_geometric: np.ndarray
    triangle: np.ndarray
    barycentric: np.ndarray
    target: np.ndarray
    texel: np.ndarray
    weight: np.ndarray

    def __len__(self) -> int:
        return len(self.p)

    def take(self, index) -> "TexelPoints":
        """The points ``index`` selects (slice, mask or integer array)."""
        if isinstance(index, np.ndarray) and index.dtype.kind in "iu":  # np.take: ~3x faster than fancy rows
            return TexelPoints(*(np.take(getattr(self, f), index, axis=0) for f in self.__dataclass_fields__))
        return TexelPoints(*(getattr(self, f)[index] for f in self.__dataclass_fields__))

    def per_texel(self, rows: np.ndarray | None = None) -> tuple["TexelPoints", np.ndarray]:
        """One point per (target, texel, triangle): the weighted centroid of its samples.

        Indirect light varies slowly across a texel, so Equation 3 at the centroid
        stands for the mean over the texel's samples (gradients make it linear there)
        at a quarter of the lookups. Samples of one triangle are merged only, so the
        centroid stays on the surface. Returns (merged points, (n,) index of each
        sample's merged point); weights add up, normals are re-normalised.
        rows : (m,) integer indices of the samples to merge, the others left out (the index returned is then
            (m,)), or None for all.
        Groups are summed in passes of whole groups (:func:`~core.executor.group_chunks`), each sample read
        by its index: whole-column temporaries would be fresh memory on every bake (Sponza at 2048^2: 11 M
        samples, 1.9 GB of them, 1.7-9.4 s mostly in the kernel); a group's sums are the same to the bit.
        """
        if rows is not None and np.asarray(rows).dtype.kind not in "iu":
            raise TypeError(f"per_texel: rows must be integer indices, got {np.asarray(rows).dtype}")
        m = len(self) if rows is None else len(rows)
        if m == 0:
            return self.take(np.zeros(0, np.int64)), np.zeros(0, np.int64)
        order, first, inverse = _sorted_groups(_group_key(self.target, self.texel, self.triangle, rows))
        # The samples in group order (None: as they are); a stable sort keeps each group's own order.
        base = rows if order is None else (order if rows is None else np.take(rows, order))
        groups = len(first)
        p, n_s, barycentric = np.empty((groups, 3)), np.empty((groups, 3)), np.empty((groups, 2))
        weight_sum = np.empty(groups)
        for s in group_chunks(first, m):
            def take(values: np.ndarray) -> np.ndarray:
                return values[s] if base is None else np.take(values, base[s], axis=0)

            g = slice(int(inverse[s.start]), int(inverse[s.stop - 1]) + 1)
            local, size = inverse[s] - g.start, g.stop - g.start
            weight = take(self.weight)
            w = weight.astype(np.float64)
            total = np.bincount(local, weights=w, minlength=size)
            # Equal weights stand in where a group's weights sum to zero, so the centroid stays finite.
            w = np.where(total[local] > 0, w, 1.0)
            total = np.bincount(local, weights=w, minlength=size)
            for values, out in ((self.p, p), (self.n_shading, n_s), (self.barycentric, barycentric)):
                values = take(values)  # the chunk's rows first: np.take copies a strided column whole
                for c in range(values.shape[1]):
                    out[g, c] = np.bincount(local, weights=w * values[:, c], minlength=size) / total
            weight_sum[g] = np.bincount(local, weights=weight, minlength=size)
        first_row = first if base is None else base[first]
        n_g = np.take(self.n_geometric, first_row, axis=0)
        length = np.linalg.norm(n_s, axis=1, keepdims=True)
        n_s = np.where(length > 1e-12, n_s / np.maximum(length, 1e-300), n_g)
        merged = TexelPoints(p, n_s, n_g, np.take(self.triangle, first_row), barycentric,
                             np.take(self.target, first_row), np.take(self.texel, first_row),
                             weight_sum.astype(np.float32))
        return merged, _unsorted(order, inverse)


def _sorted_groups(key: np.ndarray) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
    """(order, first, inverse) of keys (n,) or rows (n, k), n >= 1: ``order`` (n,) the stable sort of the keys
    (rows lexicographically, always sorted), None when 1-D keys are in order already, as rasterised samples
    come (by target, texel, triangle); ``first`` (g,) where each group of equal keys starts and ``inverse``
    (n,) intp each sorted key's group, groups in key order. With ``order``, ``order[first]`` and the inverse
    scattered back (:func:`_unsorted`) are ``np.unique(key, return_index=True, return_inverse=True)``'s."""
    if key.ndim == 1:
        order = None if not (key[1:] < key[:-1]).any() else np.argsort(key, kind="stable")
    else:
        order = np.lexsort(key.T[::-1])
    if order is not None:
        key = np.take(key, order, axis=0)
    starts = np.empty(len(key), bool)
    starts[0] = True
    if key.ndim == 1:
        np.not_equal(key[1:], key[:-1], out=starts[1:])
    else:
        np.any(key[1:] != key[:-1], axis=1, out=starts[1:])
    inverse = np.cumsum(starts, dtype=np.intp)
    inverse -= 1
    return order, np.flatnonzero(starts), inverse


def _unsorted(order: np.ndarray | None, inverse: np.ndarray) -> np.ndarray:
    """``inverse`` of keys in ``order`` (:func:`_sorted_groups`) for the keys as they were."""
    if order is None:
        return inverse
    out = np.empty_like(inverse)
    out[order] = inverse
    return out


def _group_key(target: np.ndarray, texel: np.ndarray, triangle: np.ndarray, rows: np.ndarray | None = None
               ) -> np.ndarray:
    """Keys (n,) or (n, 3) int64 whose sorted order is the lexicographic order of (target, texel, triangle),
    of the samples ``rows`` (n,) selects (None: all).

    One int64 in mixed radix when the three fit (np.unique over rows costs ~9x more: Sponza at 16
    texels/m, 3.9 M samples, 1.30 s against 0.15 s), else the rows themselves. The radix is taken over all
    samples, not only ``rows``: the keys' order, all they are for, is the same. Built in passes
    (:func:`~core.executor.row_chunks`) into one array.
    """
    columns = (target, texel, triangle)
    n = len(texel) if rows is None else len(rows)

    def part(column: np.ndarray, s: slice) -> np.ndarray:  # a copy always: the key is built in place
        return (column[s] if rows is None else np.take(column, rows[s])).astype(np.int64)

    whole = slice(None)
    if len(texel) == 0 or min(int(c.min()) for c in columns) < 0:
        return np.stack([part(c, whole) for c in columns], axis=1)
    texels, triangles = int(texel.max()) + 1, int(triangle.max()) + 1
    if (int(target.max()) + 1) * texels * triangles >= 2 ** 63:
        return np.stack([part(c, whole) for c in columns], axis=1)
    key = np.empty(n, np.int64)
    for s in row_chunks(n):
        k = part(target, s)
        k *= texels
        k += part(texel, s)
        k *= triangles
        k += part(triangle, s)
        key[s] = k
    return key


@dataclass(frozen=True)
class TargetRaster:
    """Per-target rasterisation bookkeeping: image size, coverage and Cycles' centre mask;
    ``centre_triangle``: (width * height,) the triangle under each texel's centre, -1 none (indexing the
    target's triangles of nonzero area, as :func:`footprint_texel_points` does); ``folded``: samples placed on
    it for texels a triangle edge crosses (deviation: crease-folding); ``past_edges``: the same for texels at a
    chart's edge (deviation: edge-folding)."""

    width: int
    height: int
    coverage: np.ndarray
    centre_inside: np.ndarray
    sample_slice: slice
    centre_triangle: np.ndarray
    folded: int = 0
    past_edges: int = 0


def lift_texels(scene: Scene, samples_per_axis: int, map=map, crease_folding: bool = False,
                edge_folding: bool = False, footprint_side: float = DIRECT_FOOTPRINT_SIDE
                ) -> tuple[TexelPoints, list[TargetRaster]]:
    """Rasterise every target's light-map UVs and place the samples on the surface.

    Degenerate (zero-area) triangles are dropped here: they hold no surface to light.
    map : runs the bands of texel rows (:func:`core.raster.row_bands`; an executor's ``map`` spreads them over
        threads; the points are the same).
    crease_folding : a texel with a sample off its centre triangle is sampled on that triangle (deviation:
        crease-folding, :func:`core.raster.centre_footprints`).
    edge_folding : so is a texel at a chart's edge (deviation: edge-folding, :func:`core.raster.rasterize`).
    footprint_side : the width (texels) of the square Cycles jitters a texel's bake samples in.
    """
    geometry = scene.geometry
    face_n = geometry.face_normals()
    areas = geometry.areas()
    parts, rasters, start = [], [], 0
    for target in scene.targets:
        keep = areas[target.triangles] > 0
        local = np.flatnonzero(keep)
        uv = checked_uv(target.lightmap_uv[local], target.width, target.height, samples_per_axis)
        masks = RasterMasks.empty(target.width, target.height)

        def band(rows):  # a band of texel rows; its samples are the whole map's in those rows, to the bit
            samples = rasterize_rows(uv, target.width, target.height, samples_per_axis, rows, masks,
                                     edge_folding=edge_folding, footprint_side=footprint_side)
            if not crease_folding:
                return samples, 0
            straddling = straddling_texels(samples.texel, samples.triangle, masks.centre_triangle)
            return with_centre_footprints(samples, uv, straddling, footprint_side)

        # Bands on the threads: the work per sample is numpy's over millions of rows (sorts, joins and their
        # first touch of memory), which one thread did alone (Sponza 16/m: 6.8 s, a core idle).
        bands = list(map(band, row_bands(target.height)))
        ends = np.cumsum([len(samples.texel) for samples, _ in bands])
        count = int(ends[-1]) if len(ends) else 0
        p, n_s, n_g = (np.empty((count, 3)) for _ in range(3))
        tri, b, texel, weight = np.empty(count, np.int64), np.empty((count, 2)), np.empty(count, np.int64), np.empty(
            count, np.float32)

        def lift(index: int) -> None:  # each band fills its rows: no serial join of 11 M rows (Sponza 2048^2)
            samples = bands[index][0]
            s = slice(int(ends[index]) - len(samples.texel), int(ends[index]))
            tri[s] = target.triangles[local[samples.triangle]]
            b[s], texel[s], weight[s] = samples.barycentric[:, 1:3], samples.texel, samples.weight
            p[s], n_s[s], n_g[s] = on_surface(geometry, face_n, tri[s], samples.barycentric)

        list(map(lift, range(len(bands))))
        parts.append((p, n_s, n_g, tri, b, np.full(count, len(rasters), np.int32), texel, weight))
        rasters.append(TargetRaster(target.width, target.height, masks.coverage.reshape(target.height, target.width),
                                    masks.centre_inside.reshape(target.height, target.width),
                                    slice(start, start + count), masks.centre_triangle,
                                    sum(folded for _, folded in bands), sum(samples.past_edges for samples, _ in bands)))
        start += count
    if not parts:
        empty = TexelPoints(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, np.int64),
                            np.zeros((0, 2)), np.zeros(0, np.int32), np.zeros(0, np.int64), np.zeros(0, np.float32))
        return empty, rasters
    columns = [np.concatenate(c) for c in zip(*parts)] if len(parts) > 1 else parts[0]
    return TexelPoints(*columns), rasters


def footprint_texel_points(scene: Scene, target_index: int, texels: np.ndarray, per_axis: int,
                           rng: np.random.Generator, side: float = 1.0, centre_triangle: np.ndarray | None = None
                           ) -> TexelPoints:
    """Stratified jittered points over the footprint of some texels of one target, on its surface.

    The points of :func:`core.raster.footprint_points` lifted as :func:`lift_texels` lifts the
    regular samples (same triangles kept, same normals); ``weight`` is 1 / (points of the texel),
    so a texel's weights sum to 1 over the part of it the triangles cover.

    Parameters
    ----------
    scene : the scene; ``scene.targets[target_index]`` is rasterised.
    texels : (k,) int64 unique flat texel indices y * width + x of that target's image.
    per_axis : strata per texel axis (typical 8).
    rng : the jitter's random stream.
    side : footprint width in texels, centred on the texel (:func:`core.raster.footprint_points`).
    centre_triangle : the target's :attr:`TargetRaster.centre_triangle`, or None: given, points off the
        triangle under their texel's centre are dropped, as Cycles' jitter stays on that triangle; a texel
        left with none gets its centre (deviation: crease-folding).
    """
    geometry = scene.geometry
    face_n = geometry.face_normals()
    target = scene.targets[target_index]
    local = np.flatnonzero(geometry.areas()[target.triangles] > 0)
    uv = target.lightmap_uv[local]
    texel, tri_local, b = footprint_points(uv, target.width, target.height, texels, per_axis, rng, side)
    if centre_triangle is not None and len(texel):
        texel, tri_local, b = _on_centre_triangle(texel, tri_local, b, centre_triangle, uv, target.width,
                                                  target.height)
    tri = target.triangles[local[tri_local]]
    p, n_s, n_g = on_surface(geometry, face_n, tri, b)
    counts = np.bincount(texel, minlength=target.width * target.height)
    weight = (1.0 / np.maximum(counts[texel], 1)).astype(np.float32)
    return TexelPoints(p, n_s, n_g, tri, b[:, 1:3].copy(), np.full(len(tri), target_index, np.int32), texel, weight)


def _on_centre_triangle(texel, tri, b, centre_triangle, uv, width, height):
    """Footprint points (texel, triangle, barycentric) without those off their texel's centre triangle; a
    texel that loses them all gets its centre (:func:`core.raster.on_centre_triangles`)."""
    off = off_centre_triangle(texel, tri, centre_triangle)
    if not off.any():
        return texel, tri, b
    emptied = np.setdiff1d(texel[off], texel[~off])
    p_texel = np.asarray(uv, np.float64) * [width, height]
    c_texel, c_tri, c_b, _ = on_centre_triangles(p_texel, width, emptied, centre_triangle[emptied].astype(np.int64),
                                                 np.zeros((0, 2)))
    texel, tri, b = (np.concatenate([a[~off], c]) for a, c in ((texel, c_texel), (tri, c_tri), (b, c_b)))
    order = np.argsort(texel, kind="stable")
    return texel[order], tri[order], b[order]


def on_surface(geometry, face_n, tri, b):
    """Position, shading normal and geometric normal (n, 3) of barycentrics b (n, 3) on triangles tri (n,);
    face_n : (T, 3) the geometry's :meth:`~core.scene.Geometry.face_normals`. In passes of ROW_CHUNK rows."""
    p, n_s = np.empty((len(tri), 3)), np.empty((len(tri), 3))
    n_g = np.take(face_n, tri, axis=0)
    corners, corner_normals = geometry.positions.reshape(-1, 9), geometry.normals.reshape(-1, 9)
    for s in row_chunks(len(tri)):
        p[s] = _blend(b[s], np.take(corners, tri[s], axis=0))
        n_s[s] = _normalise_or(_blend(b[s], np.take(corner_normals, tri[s], axis=0).astype(np.float64)), n_g[s])
    return p, n_s, n_g


def _blend(b, corners):
    """(n, 3) sum over corners k of b[:, k] x corners[:, 3k:3k+3] (corners (n, 9)): the sum einsum
    "nk,nkj->nj" makes, in the same order (same bits), without einsum's generic loop."""
    return b[:, 0:1] * corners[:, 0:3] + b[:, 1:2] * corners[:, 3:6] + b[:, 2:3] * corners[:, 6:9]


def splat(values: np.ndarray, points: TexelPoints, raster: TargetRaster,
          weight: np.ndarray | None = None) -> np.ndarray:
    """Weighted sum of per-sample values (n, C) into one target's image (height, width, C).

    weight : (n,) the samples' shares of their texels; None: ``points.weight``.
    """
    s = raster.sample_slice
    channels = values.shape[1]
    size = raster.height * raster.width
    w = (points.weight if weight is None else weight)[s].astype(np.float64)
    image = np.stack([np.bincount(points.texel[s], weights=values[s, c] * w, minlength=size)
                      for c in range(channels)], axis=1)
    return image.reshape(raster.height, raster.width, channels)


def _normalise_or(v: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    length = norms(v, keepdims=True)
    return np.divide(v, length, out=fallback.copy(), where=length > 1e-12)
