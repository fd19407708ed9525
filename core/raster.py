"""Conservative texel rasterisation of light-map UV triangles (lightmapper.h style).

Each texel is shaded from points that lie on the surface. A texel gets:

* **sub-samples**: the centres of a ``samples_per_axis`` x ``samples_per_axis``
  regular grid inside the texel, each belonging to the one triangle that
  contains it (on an edge shared by two triangles, or where two charts touch,
  the triangle it is most inside wins; ties go to the lower triangle index);
* with ``edge_folding`` (deviation: edge-folding), a texel whose centre lies
  in a triangle but misses a sub-sample (past a chart's edge) is sampled as
  Cycles' bake samples it instead: **on the centre's triangle, over the square
  Cycles jitters in** (:func:`centre_footprints`);
* otherwise, if a triangle overlaps the texel but no sub-sample of the texel
  falls inside any triangle (thin slivers, chart borders), **one conservative
  sample** at the centroid of (texel square clipped by the triangle), taken
  from the triangle with the largest overlap, so no covered texel is missed
  and no sample leaves the surface.

Texel space: texel (x, y) covers [x, x+1] x [y, y+1] of ``uv * (width, height)``;
row 0 is v in [0, 1/height), the bottom row, as Blender's ``Image.pixels``.

Work is vectorised over triangles batched by bounding-box size (bounding boxes
rounded up to powers of two, so a batch is one dense (m, h, w) array); huge
triangles are cut into row bands so no batch exceeds :data:`BATCH_ELEMENTS`.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .constants import CENTRE_FOOTPRINT_PER_AXIS, DIRECT_FOOTPRINT_SIDE

# Candidate points per vectorised batch (~40 bytes each in flight, so ~80 MB).
BATCH_ELEMENTS = 1 << 21
# Texel rows per band of :func:`rasterize_rows` (core/texels.py rasterises a map's bands on the bake's threads).
# A band's temporaries stay a few MB (Sponza 16 texels/m, 1388 texels wide: 128 rows took 2.4-3.9 s, 1.4-4.6 s
# of it in the kernel faulting in fresh pages; 32 rows 1.7-1.8 s, 0.3-0.4 s there).
BAND_ROWS = 32
# A point whose barycentrics are all >= -INSIDE_EPS counts as inside (closes
# float gaps on shared edges; duplicates are then resolved to one triangle).
INSIDE_EPS = 1e-9
# Where Blender's bake samples a texel (x, y), relative to its centre (x + 0.5, y + 0.5): RE_bake_pixels_populate
# scans u * width - 0.501, v * height - 0.502 (render/intern/bake.cc).
BLENDER_SCAN_OFFSET = np.array([0.001, 0.002])
# UV triangles with twice-area below this (texels^2) cover nothing and are skipped.
MIN_AREA2 = 1e-14
# Clipped overlaps below this area (texels^2) are mere contact at an edge or a corner.
MIN_OVERLAP = 1e-10


@dataclass(frozen=True)
class TexelSamples:
    """Surface sample points of a light map (struct of arrays, s samples).

    Memory: 8 + 8 + 24 + 4 + 1 = 45 bytes per sample, plus 6 bytes per texel.

    Attributes
    ----------
    texel : (s,) int64 flat texel index y * width + x, samples sorted by it.
    triangle : (s,) int64 index into the t rasterised triangles.
    barycentric : (s, 3) float64 weights of corners 0, 1, 2 (>= 0, sum 1).
    weight : (s,) float32, 1 / (samples in the texel): a texel's weights sum to 1.
    conservative : (s,) bool, True for a clipped-centroid sample (texel with no sub-sample).
    coverage : (height, width) bool, texels with at least one sample.
    centre_inside : (height, width) bool, texels whose centre lies inside a triangle or on its
        edge: the texels Cycles bakes, but for centres on an edge, of which Blender's rasteriser
        takes some only (on an axis-aligned chart those on its left and lower edges; xatlas puts
        chart corners on texel centres, so a chart's outer rows hold such centres). Compare with
        Cycles over this mask and Cycles' own coverage (a bake without margin).
    centre_triangle : (height, width) int32 the triangle under each texel's centre (the one its
        bake samples lie on in Cycles), -1 where ``centre_inside`` is False.
    width, height : light-map size in texels.
    past_edges : samples of texels at a chart's edge taken on their centre triangle (deviation: edge-folding).
    rows : (first, end) the texel rows the samples cover (:func:`rasterize_rows`), None: all of them; the masks
        are the whole image's, which the bands of one raster share and each fills its own rows of.
    """

    texel: np.ndarray
    triangle: np.ndarray
    barycentric: np.ndarray
    weight: np.ndarray
    conservative: np.ndarray
    coverage: np.ndarray
    centre_inside: np.ndarray
    centre_triangle: np.ndarray
    width: int
    height: int
    past_edges: int = 0
    rows: tuple[int, int] | None = None

    def __post_init__(self):
        s = len(self.texel)
        for name in ("triangle", "barycentric", "weight", "conservative"):
            if len(getattr(self, name)) != s:
                raise ValueError(f"TexelSamples.{name} has {len(getattr(self, name))} rows, texel has {s}")
        if any(m.shape != (self.height, self.width) for m in (self.coverage, self.centre_inside, self.centre_triangle)):
            raise ValueError("TexelSamples: coverage masks must be (height, width)")

    @property
    def count(self) -> int:
        return len(self.texel)

    @property
    def span(self) -> tuple[int, int]:
        """(first, end) flat texel indices of the rows the samples cover."""
        first, end = self.rows or (0, self.height)
        return first * self.width, end * self.width

    def uv_texel(self, uv: np.ndarray) -> np.ndarray:
        """(s, 2) float64 sample positions in texel units (x right, y up), from the rasterised ``uv``."""
        p = np.asarray(uv, np.float64)[self.triangle] * [self.width, self.height]
        return np.einsum("sk,skd->sd", self.barycentric, p)


# --------------------------------------------------------------------------- public
def rasterize(uv: np.ndarray, width: int, height: int, samples_per_axis: int = 2, map=map,
              edge_folding: bool = False, footprint_side: float = DIRECT_FOOTPRINT_SIDE) -> TexelSamples:
    """Sample points for every texel that the UV triangles cover.

    Parameters
    ----------
    uv : (t, 3, 2) float32 light-map UVs per triangle corner, [0, 1] (parts outside
        the square are ignored).
    width, height : light-map size in texels (typical 64-2048).
    samples_per_axis : sub-samples per texel axis (typical 2: four points per texel).
    map : runs the batches of triangles (an executor's ``map`` spreads them over threads: the
        result is the same, batches are joined in order).
    edge_folding : a texel whose centre lies in a triangle but misses a sub-sample takes the samples
        :func:`centre_footprints` places instead of its own (deviation: edge-folding).
    footprint_side : with ``edge_folding``, the width (texels) of the square Cycles jitters a texel's bake
        samples in (:data:`~core.constants.DIRECT_FOOTPRINT_SIDE`).

    Returns
    -------
    TexelSamples

    Notes
    -----
    Measured on the reference machine (2 cores, shared with other jobs), 65k
    triangles of an unwrapped height field, 2x2 samples: 1024x1024 in 2.3 s
    (2.1 M samples), 2048x2048 in 13 s (8.3 M samples).
    """
    uv = checked_uv(uv, width, height, samples_per_axis)
    masks = RasterMasks.empty(int(width), int(height))
    return rasterize_rows(uv, int(width), int(height), int(samples_per_axis), (0, int(height)), masks, map,
                          edge_folding, footprint_side)


def checked_uv(uv, width, height, samples_per_axis) -> np.ndarray:
    """``uv`` as an array, after the checks :func:`rasterize` makes (ValueError naming what is wrong)."""
    uv = np.asarray(uv)
    if uv.ndim != 3 or uv.shape[1:] != (3, 2):
        raise ValueError(f"rasterize: uv must be (t, 3, 2), got {uv.shape}")
    if not np.isfinite(uv).all():
        bad = np.flatnonzero(~np.isfinite(uv).reshape(len(uv), -1).all(axis=1))
        raise ValueError(f"rasterize: {len(bad)} UV triangles have non-finite coordinates, first triangle {bad[0]}")
    if width < 1 or height < 1 or samples_per_axis < 1:
        raise ValueError(f"rasterize: bad size {width}x{height} or samples_per_axis {samples_per_axis}")
    return uv


@dataclass(frozen=True)
class RasterMasks:
    """The per-texel masks of one raster, flat (width * height,), that its row bands fill: coverage and
    centre_inside bool, centre_triangle int32 (-1: none); see :class:`TexelSamples`."""

    width: int
    height: int
    coverage: np.ndarray
    centre_inside: np.ndarray
    centre_triangle: np.ndarray

    @staticmethod
    def empty(width: int, height: int) -> "RasterMasks":
        size = width * height
        return RasterMasks(width, height, np.zeros(size, bool), np.zeros(size, bool), np.full(size, -1, np.int32))


def row_bands(height: int, rows: int = BAND_ROWS) -> list[tuple[int, int]]:
    """(first, end) texel rows of the bands :func:`rasterize_rows` rasterises an image of ``height`` rows in."""
    return [(first, min(first + rows, height)) for first in range(0, height, rows)]


def rasterize_rows(uv: np.ndarray, width: int, height: int, samples_per_axis: int, rows: tuple[int, int],
                   masks: RasterMasks, map=map, edge_folding: bool = False,
                   footprint_side: float = DIRECT_FOOTPRINT_SIDE) -> TexelSamples:
    """:func:`rasterize` over the texel rows [first, end) ``rows`` alone: the samples of those rows, the same
    to the bit as the whole image's (every test a sample passes is its texel's own, in the image's
    coordinates), their rows of ``masks`` filled. Bands of one image run on threads of their own: they write
    disjoint rows of the masks they share."""
    width, height, n = int(width), int(height), int(samples_per_axis)
    first, end = rows
    lo, hi = first * width, end * width
    p_texel = uv.astype(np.float64) * [width, height]

    # -- sub-samples: n x n grid per texel, one triangle per point
    sample, tri, bary = _grid_hits(p_texel, width, height, n, map, rows)

    # -- texel centres (the texels Cycles bakes, and those whose centre lies on an edge)
    centre, centre_tri, _ = _grid_hits(p_texel, width, height, 1, map, rows)
    masks.centre_inside[centre] = True
    masks.centre_triangle[centre] = centre_tri
    # Blender's bake gives a texel to the triangle under (x + 0.501, y + 0.502), not its centre: where the
    # centre lies on a shared edge (xatlas puts chart corners on texel centres) that decides which
    # triangle Cycles jitters on. Texels whose scan point is on no triangle keep their centre's.
    scan, scan_tri, _ = _grid_hits(p_texel - BLENDER_SCAN_OFFSET, width, height, 1, map, rows)
    keep = masks.centre_inside[scan]
    masks.centre_triangle[scan[keep]] = scan_tri[keep]

    sx, sy = sample % (width * n), sample // (width * n)
    texel = (sy // n) * width + sx // n
    has_sample = np.zeros(hi - lo, bool)  # the band's texels
    has_sample[texel - lo] = True

    # -- conservative samples: overlapped texels without any sub-sample
    c_texel, c_tri, c_bary = _clipped_centroids(p_texel, width, height, has_sample, map, rows)

    texel = np.concatenate([texel, c_texel])
    tri = np.concatenate([tri, c_tri])
    bary = np.concatenate([bary, c_bary])
    conservative = np.concatenate([np.zeros(len(sample), bool), np.ones(len(c_texel), bool)])
    samples = _sorted_samples(texel, tri, bary, conservative, masks, rows)
    if edge_folding:  # deviation: edge-folding, docs/DEVIATIONS.md
        held = np.bincount(samples.texel[~samples.conservative] - lo, minlength=hi - lo)
        fold = lo + np.flatnonzero(masks.centre_inside[lo:hi] & (held < n * n))
        samples, placed = with_centre_footprints(samples, uv, fold, footprint_side)
        samples = replace(samples, past_edges=placed)
    return samples


def _sorted_samples(texel, tri, bary, conservative, masks: RasterMasks, rows: tuple[int, int],
                    past_edges: int = 0, share: np.ndarray | None = None) -> TexelSamples:
    """A :class:`TexelSamples` of unordered samples of texel ``rows``: sorted by texel (then triangle), each
    texel's weights 1 / its samples, or with ``share`` (s,) each sample's share over its texel's sum of them;
    the rows' coverage written to ``masks``."""
    width, height = masks.width, masks.height
    lo, hi = rows[0] * width, rows[1] * width
    order = _texel_order(texel, tri)
    texel, tri, bary, conservative = texel[order], tri[order], bary[order], conservative[order]
    counts = np.bincount(texel - lo, minlength=hi - lo)
    held = counts[counts > 0]
    if share is None:
        weight = np.repeat((1.0 / held).astype(np.float32), held)  # texels ascend: each texel's run of samples
    else:
        share = np.asarray(share, np.float64)[order]
        weight = (share / np.bincount(texel - lo, weights=share, minlength=hi - lo)[texel - lo]).astype(np.float32)
    masks.coverage[lo:hi] = counts > 0
    return TexelSamples(texel, tri, bary, weight, conservative, masks.coverage.reshape(height, width),
                        masks.centre_inside.reshape(height, width), masks.centre_triangle.reshape(height, width),
                        width, height, past_edges, None if tuple(rows) == (0, height) else tuple(rows))


def with_centre_footprints(samples: TexelSamples, uv: np.ndarray, texels: np.ndarray, side: float
                           ) -> tuple[TexelSamples, int]:
    """(``samples`` with every sample of ``texels`` ((k,) unique flat indices of texels whose centre lies on a
    triangle) replaced by :func:`centre_footprints`, the number of samples placed)."""
    texels = np.asarray(texels, np.int64)
    if len(texels) == 0:
        return samples, 0
    width, height = samples.width, samples.height
    p_texel = np.asarray(uv, np.float64) * [width, height]
    f_texel, f_tri, f_bary, f_share = centre_footprints(p_texel, width, texels,
                                                        samples.centre_triangle.reshape(-1)[texels].astype(np.int64),
                                                        side)
    lo, hi = samples.span
    replaced = np.zeros(hi - lo, bool)
    replaced[texels - lo] = True
    keep = ~replaced[samples.texel - lo]
    masks = RasterMasks(width, height, samples.coverage.reshape(-1), samples.centre_inside.reshape(-1),
                        samples.centre_triangle.reshape(-1))
    return _sorted_samples(np.concatenate([samples.texel[keep], f_texel]),
                           np.concatenate([samples.triangle[keep], f_tri]),
                           np.concatenate([samples.barycentric[keep], f_bary]),
                           np.concatenate([samples.conservative[keep], np.zeros(len(f_texel), bool)]),
                           masks, samples.rows or (0, height),
                           samples.past_edges, np.concatenate([samples.weight[keep], f_share])), len(f_texel)


def centre_footprints(p_texel: np.ndarray, width: int, texels: np.ndarray, centre_tri: np.ndarray, side: float,
                      per_axis: int = CENTRE_FOOTPRINT_PER_AXIS) -> tuple[np.ndarray, ...]:
    """(texel (f,), triangle (f,), barycentric (f, 3), share (f,)): texels sampled as Cycles' bake samples
    them, on the triangle under their centre only.

    Cycles jitters a texel's bake samples over the square of ``side`` texels centred on it and keeps them on
    that triangle (a 10.8 m x 1.5 cm strip charted one texel wide: Cycles 5.0.1's Diffuse Direct within 0.3 %
    of the jitter restricted to the triangle and 22x off from the barycentric mirror of Blender 3's bake kernel,
    tests/test_folding.py). Here the jitter's ``per_axis`` x ``per_axis`` strata centres over
    that square stand for it, those on the triangle; a texel none of whose strata lie on it (a sliver
    narrower than a stratum) gets its centre, which does. A stratum centre on the triangle's edge stands for
    a stratum the edge halves: its share is 1/2 (xatlas puts chart corners on texel centres, so a chart's
    diagonal runs through a texel's diagonal strata: counted whole, they pulled the mean of the texel's half
    towards the edge).

    p_texel : (t, 3, 2) the UV triangles in texel units; texels : (k,) flat texel indices; centre_tri : (k,)
    the triangle (indexing ``p_texel``) under each one's centre.
    """
    m = int(per_axis)
    steps = ((np.arange(m) + 0.5) / m - 0.5) * side
    offsets = np.stack(np.meshgrid(steps, steps, indexing="xy"), axis=-1).reshape(-1, 2)
    return on_centre_triangles(p_texel, width, texels, centre_tri, offsets)


def on_centre_triangles(p_texel: np.ndarray, width: int, texels: np.ndarray, centre_tri: np.ndarray,
                        offsets: np.ndarray) -> tuple[np.ndarray, ...]:
    """(texel (f,), triangle (f,), barycentric (f, 3), share (f,)): the points at each texel's centre plus
    ``offsets`` ((m, 2) for all texels, or (k, m, 2), texel units) that lie on its centre triangle
    ``centre_tri`` (k,), as Cycles keeps its bake jitter there; a texel none of whose points do gets its
    centre, which does. ``share``: 1/2 for a point on the triangle's edge, 1 inside.
    p_texel : (t, 3, 2) the UV triangles in texel units; texels : (k,) flat texel indices."""
    k = len(texels)
    centre = np.stack([texels % width + 0.5, texels // width + 0.5], axis=1)
    offsets = np.broadcast_to(offsets, (k,) + np.shape(offsets)[-2:])
    points = np.concatenate([centre[:, None, :] + offsets, centre[:, None, :]], axis=1)  # each centre last
    m = points.shape[1]
    texel, tri = np.repeat(texels, m), np.repeat(centre_tri, m)
    corners = p_texel[tri]
    bary = np.stack(barycentric_weights(corners, points[..., 0].ravel(), points[..., 1].ravel(),
                                        twice_area(corners)), axis=1)
    on = (bary >= -INSIDE_EPS).all(axis=1).reshape(k, m)
    on[:, -1] = ~on[:, :-1].any(axis=1)  # the centre only where no other point lies on the triangle
    on = on.ravel()
    share = np.where(bary[on].min(axis=1) <= INSIDE_EPS, 0.5, 1.0)
    bary = np.clip(bary[on], 0.0, None)
    return texel[on], tri[on], bary / bary.sum(axis=1, keepdims=True), share


# --------------------------------------------------------------------------- batching
def _next_pow2(x: np.ndarray) -> np.ndarray:
    return (1 << np.ceil(np.log2(np.maximum(x, 1))).astype(np.int64)).astype(np.int64)


def _batches(lo_x, lo_y, hi_x, hi_y):
    """Cut inclusive integer boxes into batches of equal power-of-two size.

    Yields (item, x0, y0, x1, y1, bw, bh): ``item`` indexes the input boxes; the
    box rows may be a band of the original box (huge boxes are cut into bands).
    """
    w = hi_x - lo_x + 1
    h = hi_y - lo_y + 1
    bw = _next_pow2(w)
    band = np.maximum(1, BATCH_ELEMENTS // bw)  # rows per band so one item fits a batch
    bands = -(-h // band)
    item = np.repeat(np.arange(len(w)), bands)
    first = np.repeat(np.cumsum(bands) - bands, bands)
    k = np.arange(len(item)) - first
    y0 = lo_y[item] + k * band[item]
    y1 = np.minimum(y0 + band[item] - 1, hi_y[item])
    bh = _next_pow2(y1 - y0 + 1)
    bw = bw[item]
    key = np.log2(bw).astype(np.int64) * 64 + np.log2(bh).astype(np.int64)
    order = np.argsort(key, kind="stable")
    bounds = np.flatnonzero(np.diff(key[order])) + 1
    for group in np.split(order, bounds):
        if len(group) == 0:
            continue
        gw, gh = int(bw[group[0]]), int(bh[group[0]])
        per = max(1, BATCH_ELEMENTS // (gw * gh))
        for s in range(0, len(group), per):
            g = group[s:s + per]
            it = item[g]
            yield it, lo_x[it], y0[g], hi_x[it], y1[g], gw, gh


def barycentric_weights(p, x, y, area2):
    """Barycentrics (3, ...) of points (x, y) in triangles p (m, 3, 2) (broadcast over trailing dims)."""
    extra = (slice(None),) + (None,) * (x.ndim - 1)
    x0, y0 = p[:, 0, 0][extra], p[:, 0, 1][extra]
    x1, y1 = p[:, 1, 0][extra], p[:, 1, 1][extra]
    x2, y2 = p[:, 2, 0][extra], p[:, 2, 1][extra]
    a = area2[extra]
    b1 = ((x - x0) * (y2 - y0) - (y - y0) * (x2 - x0)) / a
    b2 = ((x1 - x0) * (y - y0) - (y1 - y0) * (x - x0)) / a
    return 1.0 - b1 - b2, b1, b2


def twice_area(p):
    return (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0])


# --------------------------------------------------------------------------- sub-samples
def _grid_raw(p_texel, width, height, n, map=map, rows: tuple[int, int] | None = None):
    """All (grid point, triangle) pairs with the point inside the triangle (up to
    INSIDE_EPS). Returns (sample (k,) int64 flat index sy * width * n + sx,
    triangle (k,) int64, barycentric (k, 3) float64, least barycentric (k,)).
    rows : (first, end) the texel rows whose grid points are tested; None: all."""
    q = p_texel * n - 0.5  # grid point (sx, sy) sits at q = (sx, sy)
    gw = width * n
    first, end = rows or (0, height)
    area2 = twice_area(q)
    lo_x = np.maximum(np.ceil(q[:, :, 0].min(1) - 1e-9), 0).astype(np.int64)
    hi_x = np.minimum(np.floor(q[:, :, 0].max(1) + 1e-9), gw - 1).astype(np.int64)
    lo_y = np.maximum(np.ceil(q[:, :, 1].min(1) - 1e-9), first * n).astype(np.int64)
    hi_y = np.minimum(np.floor(q[:, :, 1].max(1) + 1e-9), end * n - 1).astype(np.int64)
    live = np.flatnonzero((hi_x >= lo_x) & (hi_y >= lo_y) & (np.abs(area2) > MIN_AREA2 * n * n))

    def batch(args):
        item, x0, y0, x1, y1, bw, bh = args
        k = live[item]
        sx = x0[:, None, None] + np.arange(bw)[None, None, :]
        sy = y0[:, None, None] + np.arange(bh)[None, :, None]
        b0, b1, b2 = barycentric_weights(q[k], sx.astype(np.float64), sy.astype(np.float64), area2[k])
        least = np.minimum(np.minimum(b0, b1), b2)
        inside = (least >= -INSIDE_EPS) & (sx <= x1[:, None, None]) & (sy <= y1[:, None, None])
        m, r, c = np.nonzero(inside)
        return (sy[m, r, 0] * gw + sx[m, 0, c], k[m], np.stack([b0[m, r, c], b1[m, r, c], b2[m, r, c]], axis=1),
                least[m, r, c])

    parts = list(map(batch, _batches(lo_x[live], lo_y[live], hi_x[live], hi_y[live]))) if len(live) else []
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0)
    return tuple(np.concatenate(column) for column in zip(*parts))


def _grid_hits(p_texel, width, height, n, map=map, rows: tuple[int, int] | None = None):
    """Points of the n x n per-texel grid inside triangles, each given to one triangle.

    Returns (sample (k,) int64 flat index sy * width * n + sx, triangle (k,) int64,
    barycentric (k, 3) float64), unique in ``sample`` and in increasing order of it.
    rows : (first, end) the texel rows whose grid points are tested; None: all.
    """
    sample, tri, bary, least = _grid_raw(p_texel, width, height, n, map, rows)
    first, end = rows or (0, height)
    start = first * n * (width * n)  # the rows' first grid point: the tables span the rows alone
    pick = _one_per_sample(sample - start, tri, least, (width * n) * ((end - first) * n))
    return sample[pick], tri[pick], _normalise(bary[pick])


DENSE_GRID_PER_PAIR = 4
"""Grid points per (point, triangle) pair up to which :func:`_one_per_sample` uses dense tables."""


def _one_per_sample(sample, tri, least, grid_points: int) -> np.ndarray:
    """Indices of one pair per grid point, in increasing ``sample``: the triangle the point is most
    inside (largest ``least``), then the lowest triangle index.

    Only points on shared edges have several pairs (a few percent), so only they are sorted; the
    rest are placed by their sample index (a 3-key sort of every pair cost 0.4 s per million). The
    two tables of grid points that takes (16 bytes each) are used only while the pairs fill a
    quarter of the grid; a map with few charts sorts every pair instead.
    """
    if len(sample) == 0:
        return np.zeros(0, np.int64)
    if grid_points > DENSE_GRID_PER_PAIR * len(sample):
        order = np.lexsort((tri, -least, sample))
        return order[np.r_[True, sample[order][1:] != sample[order][:-1]]]
    count = np.bincount(sample, minlength=grid_points)
    chosen = np.full(grid_points, -1, np.int64)
    single = np.flatnonzero(count[sample] == 1)
    chosen[sample[single]] = single
    shared = np.flatnonzero(count[sample] > 1)
    if len(shared):
        order = shared[np.lexsort((tri[shared], -least[shared], sample[shared]))]
        head = order[np.r_[True, sample[order][1:] != sample[order][:-1]]]
        chosen[sample[head]] = head
    return chosen[chosen >= 0]


def overlapping(uv: np.ndarray, width: int, height: int, samples_per_axis: int = 4,
                depth: float = 1e-6) -> np.ndarray:
    """Which UV triangles overlap another one.

    Parameters
    ----------
    uv : (t, 3, 2) float32 UVs in [0, 1].
    width, height : texel grid the test runs on.
    samples_per_axis : test points per texel axis (typical 4).
    depth : a point counts as inside when all its barycentrics exceed this, so
        triangles that merely share an edge do not overlap.

    Returns
    -------
    (t,) bool : True for triangles that share a test point with another triangle.
    """
    p_texel = np.asarray(uv, np.float64) * [width, height]
    sample, tri, _, least = _grid_raw(p_texel, int(width), int(height), int(samples_per_axis))
    keep = least > depth
    sample, tri = sample[keep], tri[keep]
    out = np.zeros(len(p_texel), bool)
    if len(sample):
        order = np.argsort(sample, kind="stable")
        s = sample[order]
        dup = np.r_[s[1:] == s[:-1], False] | np.r_[False, s[1:] == s[:-1]]
        out[tri[order][dup]] = True
    return out


def _normalise(bary):
    """Barycentrics (k, 3) float64 clipped at 0 and summing to 1, in place: every caller passes an array of its
    own (a fresh copy's first touch costs more than the arithmetic: Sponza 2048^2's 11 M samples 2.6 -> 0.4 s)."""
    np.maximum(bary, 0.0, out=bary)
    bary /= ((bary[:, 0] + bary[:, 1]) + bary[:, 2])[:, None]
    return bary


def _texel_order(texel: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """The permutation ``np.lexsort((tri, texel))`` gives (by texel, then triangle, ties in their order), from
    one stable sort of a combined key where it fits in int64 (0.8 -> 0.2 s for Sponza 2048^2's samples).
    texel, tri : (k,) int64."""
    if len(texel) == 0:
        return np.zeros(0, np.int64)
    span = int(tri.max()) + 1
    if int(texel.max()) >= np.iinfo(np.int64).max // span:
        return np.lexsort((tri, texel))
    return np.argsort(texel * span + tri, kind="stable")


# --------------------------------------------------------------------------- conservative samples
def _clipped_centroids(p_texel, width, height, has_sample, map=map, rows: tuple[int, int] | None = None):
    """One sample per texel that triangles overlap but no sub-sample reached: the
    centroid of (texel square clipped by the triangle) of the largest overlap.

    has_sample : (texels of ``rows``,) bool, the rows' texels a sub-sample reached.
    rows : (first, end) the texel rows to sample; None: all.
    Returns (texel (c,) int64, triangle (c,) int64, barycentric (c, 3) float64).
    """
    top, end = rows or (0, height)
    area2 = twice_area(p_texel)
    lo_x = np.maximum(np.floor(p_texel[:, :, 0].min(1)), 0).astype(np.int64)
    hi_x = np.minimum(np.ceil(p_texel[:, :, 0].max(1)) - 1, width - 1).astype(np.int64)
    lo_y = np.maximum(np.floor(p_texel[:, :, 1].min(1)), top).astype(np.int64)
    hi_y = np.minimum(np.ceil(p_texel[:, :, 1].max(1)) - 1, end - 1).astype(np.int64)
    live = np.flatnonzero((hi_x >= lo_x) & (hi_y >= lo_y) & (np.abs(area2) > MIN_AREA2))

    def batch(args):
        item, x0, y0, x1, y1, bw, bh = args
        k = live[item]
        tx = x0[:, None, None] + np.arange(bw)[None, None, :]
        ty = y0[:, None, None] + np.arange(bh)[None, :, None]
        valid = (tx <= x1[:, None, None]) & (ty <= y1[:, None, None])
        flat = ty * width + tx
        valid &= ~has_sample[np.where(valid, flat - top * width, 0)]
        m, r, c = np.nonzero(valid)
        if len(m) == 0:
            return None
        kk = k[m]
        area, centroid = _clip_to_texels(p_texel[kk], tx[m, 0, c], ty[m, r, 0])
        keep = area > MIN_OVERLAP
        return flat[m, r, c][keep], kk[keep], area[keep], centroid[keep]

    parts = list(map(batch, _batches(lo_x[live], lo_y[live], hi_x[live], hi_y[live]))) if len(live) else []
    parts = [part for part in parts if part is not None and len(part[0])]
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    texel, tri, area, centroid = (np.concatenate(column) for column in zip(*parts))
    order = np.lexsort((tri, -area, texel))  # largest overlap first, then lowest index
    first = order[np.r_[True, texel[order][1:] != texel[order][:-1]]]
    texel, tri, centroid = texel[first], tri[first], centroid[first]
    b0, b1, b2 = barycentric_weights(p_texel[tri], centroid[:, 0], centroid[:, 1], area2[tri])
    return texel, tri, _normalise(np.stack([b0, b1, b2], axis=1))


def _clip_to_texels(tri, tx, ty):
    """Clip triangles (m, 3, 2) to texel squares [tx, tx+1] x [ty, ty+1] (Sutherland-Hodgman,
    vectorised over m). Returns (area (m,) texels^2, centroid (m, 2) texel units)."""
    m = len(tri)
    cap = 8  # a triangle clipped by 4 half-planes has at most 7 vertices
    poly = np.zeros((m, cap, 2))
    poly[:, :3] = tri
    count = np.full(m, 3)
    for axis, bound, sign in ((0, tx, 1.0), (0, tx + 1, -1.0), (1, ty, 1.0), (1, ty + 1, -1.0)):
        poly, count = _clip_half_plane(poly, count, axis, bound.astype(np.float64), sign)
    # shoelace area and centroid over the valid vertices
    idx = np.arange(cap)[None, :]
    nxt = np.where(idx + 1 < count[:, None], idx + 1, 0)
    a = poly
    b = np.take_along_axis(poly, nxt[:, :, None], axis=1)
    cross = a[:, :, 0] * b[:, :, 1] - b[:, :, 0] * a[:, :, 1]
    cross = np.where(idx < count[:, None], cross, 0.0)
    area_signed = 0.5 * cross.sum(1)
    safe = np.where(np.abs(area_signed) > 0, area_signed, 1.0)
    cx = ((a[:, :, 0] + b[:, :, 0]) * cross).sum(1) / (6 * safe)
    cy = ((a[:, :, 1] + b[:, :, 1]) * cross).sum(1) / (6 * safe)
    area = np.where(count >= 3, np.abs(area_signed), 0.0)
    return area, np.stack([cx, cy], axis=1)


def _clip_half_plane(poly, count, axis, bound, sign):
    """Keep the part of each polygon where sign * (coord[axis] - bound) >= 0."""
    m, cap, _ = poly.shape
    idx = np.arange(cap)[None, :]
    exists = idx < count[:, None]
    nxt = np.where(idx + 1 < count[:, None], idx + 1, 0)
    a = poly
    b = np.take_along_axis(poly, nxt[:, :, None], axis=1)
    da = sign * (a[:, :, axis] - bound[:, None])
    db = sign * (b[:, :, axis] - bound[:, None])
    in_a, in_b = da >= 0, db >= 0
    denom = np.where(da != db, da - db, 1.0)
    t = (da / denom)[:, :, None]
    crossing = a + t * (b - a)
    crossing[:, :, axis] = np.broadcast_to(bound[:, None], (m, cap))  # exact on the clip line
    out = np.stack([a, crossing], axis=2).reshape(m, 2 * cap, 2)
    emit = np.stack([in_a & exists, (in_a != in_b) & exists], axis=2).reshape(m, 2 * cap)
    order = np.argsort(~emit, axis=1, kind="stable")[:, :cap]
    new_count = np.minimum(emit.sum(1), cap)
    return np.take_along_axis(out, order[:, :, None], axis=1), new_count


# --------------------------------------------------------------------------- footprint points
def footprint_points(uv: np.ndarray, width: int, height: int, texels: np.ndarray, per_axis: int,
                     rng: np.random.Generator, side: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stratified jittered points over the footprint of chosen texels, each on the triangle holding it.

    Texel (x, y)'s footprint is the square of ``side`` texels centred on (x + 1/2, y + 1/2); it gets
    ``per_axis`` x ``per_axis`` strata, one uniform point in each; a point inside several triangles
    goes to the one it is most inside (then the lowest index, as :func:`rasterize`), a point inside
    none is dropped. The points are thus uniform over the part of the footprint the triangles cover
    (clipped to them), and their count per texel is that part's area in strata.

    Parameters
    ----------
    uv : (t, 3, 2) float32 light-map UVs per triangle corner, [0, 1].
    width, height : light-map size in texels.
    texels : (k,) int64 flat texel indices y * width + x, unique.
    per_axis : strata per texel axis (typical 8: 64 points).
    rng : the jitter's random stream; draws (k, per_axis, per_axis, 2) uniforms in ``texels``' order.
    side : footprint width in texels (1 = the texel; Cycles bakes 0.5, see DIRECT_FOOTPRINT_SIDE).

    Returns
    -------
    texel (s,) int64, triangle (s,) int64 index into ``uv``, barycentric (s, 3) float64; sorted by texel.
    """
    texels = np.asarray(texels, np.int64)
    m = int(per_axis)
    jitter = rng.random((len(texels), m, m, 2))
    if len(texels) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    strata = np.stack(np.meshgrid(np.arange(m), np.arange(m), indexing="xy"), axis=-1)  # (m, m, 2): (sx, sy)
    corner = np.stack([texels % width, texels // width], axis=1) + 0.5 * (1.0 - side)
    p_texel = np.asarray(uv, np.float64) * [width, height]
    # points in texel units, (k, m*m, 2)
    pts = corner[:, None, :] + (side * (strata[None] + jitter) / m).reshape(len(texels), m * m, 2)
    slot = np.full(width * height, -1, np.int64)
    slot[texels] = np.arange(len(texels))
    pair_slot, pair_tri = _footprint_pairs(p_texel, width, height, slot)
    area2 = twice_area(p_texel)
    found_point, found_tri, found_bary, found_depth = [], [], [], []
    per_batch = max(1, BATCH_ELEMENTS // (m * m))
    for s in range(0, len(pair_slot), per_batch):
        ps, pt = pair_slot[s:s + per_batch], pair_tri[s:s + per_batch]
        q = pts[ps]
        b0, b1, b2 = barycentric_weights(p_texel[pt], q[..., 0], q[..., 1], area2[pt])
        least = np.minimum(np.minimum(b0, b1), b2)
        r, c = np.nonzero(least >= -INSIDE_EPS)
        found_point.append(ps[r] * (m * m) + c)
        found_tri.append(pt[r])
        found_bary.append(np.stack([b0[r, c], b1[r, c], b2[r, c]], axis=1))
        found_depth.append(least[r, c])
    if not found_point:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    point, tri = np.concatenate(found_point), np.concatenate(found_tri)
    bary, depth = np.concatenate(found_bary), np.concatenate(found_depth)
    order = np.lexsort((tri, -depth, point))  # one triangle per point: most inside, then lowest index
    first = order[np.r_[True, point[order][1:] != point[order][:-1]]] if len(point) else order
    return texels[point[first] // (m * m)], tri[first], _normalise(bary[first])


def _footprint_pairs(p_texel, width, height, slot):
    """(texel slot, triangle) pairs whose bounding boxes meet, for texels with ``slot`` >= 0."""
    lo_x = np.maximum(np.floor(p_texel[:, :, 0].min(1)), 0).astype(np.int64)
    hi_x = np.minimum(np.ceil(p_texel[:, :, 0].max(1)) - 1, width - 1).astype(np.int64)
    lo_y = np.maximum(np.floor(p_texel[:, :, 1].min(1)), 0).astype(np.int64)
    hi_y = np.minimum(np.ceil(p_texel[:, :, 1].max(1)) - 1, height - 1).astype(np.int64)
    live = (hi_x >= lo_x) & (hi_y >= lo_y) & (np.abs(twice_area(p_texel)) > MIN_AREA2)
    # only triangles whose box holds a chosen texel (summed-area table of the chosen texels)
    table = np.zeros((height + 1, width + 1), np.int64)
    table[1:, 1:] = (slot >= 0).reshape(height, width).cumsum(0).cumsum(1)
    x0, y0 = np.clip(lo_x, 0, width), np.clip(lo_y, 0, height)
    x1, y1 = np.clip(hi_x + 1, 0, width), np.clip(hi_y + 1, 0, height)
    live &= table[y1, x1] - table[y0, x1] - table[y1, x0] + table[y0, x0] > 0
    live = np.flatnonzero(live)
    slots, tris = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    if len(live):
        for item, x0, y0, x1, y1, bw, bh in _batches(lo_x[live], lo_y[live], hi_x[live], hi_y[live]):
            tx = x0[:, None, None] + np.arange(bw)[None, None, :]
            ty = y0[:, None, None] + np.arange(bh)[None, :, None]
            valid = (tx <= x1[:, None, None]) & (ty <= y1[:, None, None])
            s = slot[np.where(valid, ty * width + tx, 0)]
            m, r, c = np.nonzero(valid & (s >= 0))
            slots.append(s[m, r, c])
            tris.append(live[item][m])
    return np.concatenate(slots), np.concatenate(tris)
