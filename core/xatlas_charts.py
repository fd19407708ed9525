"""The xatlas passes of the light-map unwrap (run in a child process by :mod:`core.unwrap`).

1. **Pass 1, charting.** xatlas segments the triangles into charts,
   parametrises and packs them (``ChartOptions`` defaults; ``PackOptions`` with
   ``resolution``, ``padding``, ``bilinear=True``). This is the slow step (~7 s
   for a 65k-triangle grid) and is why results are cached. Not ``blockAlign``:
   aligning charts to 4x4 blocks stretches small ones unevenly, so their texels
   stop being square (see :func:`pack_options`).
2. **Polygon fix.** Blender stores one UV per polygon corner (loop), but
   xatlas only sees the polygon's triangles and may put them in different
   charts (measured on a 40x40 quad grid: 0 of 1600 planar quads split, 62 of
   1600 on a wavy surface, 622 of 1600 with noisy heights). The binding has no
   way to pass polygons (xatlas's ``faceVertexCount`` is not exposed), so split
   polygons are repaired afterwards: the triangles of a split polygon are
   unfolded, edge by edge, into the chart of its largest part.
3. **Pass 2, repacking.** xatlas does not keep to the requested resolution
   (asked for 512 it returns e.g. 612x601). The charts are repacked with
   ``use_input_mesh_uvs=True`` (tens of milliseconds: charts are kept, only
   packed again) with ``texels_per_unit`` scaled until the atlas fits in
   ``resolution x resolution`` and nearly fills it; UVs are then expressed in
   [0, 1] of the *requested* resolution, so chart padding stays exactly
   ``padding`` texels and texels stay square. When no scale fits (many small
   charts: each takes at least a texel plus padding) and growing is allowed,
   the map grows by :data:`GROWTH` until the charts pack. With a texel density
   (``texels_per_unit``) the map is first made as large as the charts need at that
   density (:func:`side_at_density`): a map sized from the surface area alone cannot
   hold them (padding and the least size of small charts take part of every map), and
   xatlas would scale every chart down to fit (the occluded building of the bench at
   4 texels/m: its large walls at 0.94 per metre).
4. **Overlap repair.** xatlas can fold a chart onto itself where surfaces are
   stacked (coplanar faces with their own vertices, differently triangulated:
   12 texel centres on Sponza) or duplicated, or fold a sliver of a chart over its
   neighbour (Sponza's round columns at 16 texels/m: cap triangles a hundredth of a
   texel over the side triangles). Every polygon whose UV triangles share a test
   point with another polygon's (except one polygon per point; the points: texel
   centres and 2x2 per texel) is taken out as an island of its own, laid flat on
   its best-fit plane at the chart scale, and the charts are packed again, for up
   to :data:`REPAIR_ROUNDS` rounds (:func:`_polygons_to_detach`).
"""
from __future__ import annotations

import math

import numpy as np
import xatlas

from .uv_overlap import overlap_points

# Pass-2 repacking: at most this many packings to fit one resolution.
MAX_PACK_ATTEMPTS = 10
# Pass 2 is skipped when pass 1's atlas already fits and fills at least this much of it.
GOOD_FILL = 0.95
# A map that cannot hold the charts grows by this factor per try (rounded up to 4 texels).
GROWTH = 1.25
# Overlap repair: test points per texel axis besides the centres (2: the bake's samples, and overlaps
# thinner than a texel), rounds.
REPAIR_SAMPLES = 2
REPAIR_ROUNDS = 5


class PackError(RuntimeError):
    """xatlas could not pack the charts into the largest allowed map; ``minimum`` is a size
    that was seen to hold them (0 if unknown)."""

    def __init__(self, message: str, minimum: int = 0):
        super().__init__(message)
        self.minimum = minimum


def chart_options(variant: int) -> "xatlas.ChartOptions":
    """xatlas chart options; variant 0 is xatlas's defaults, higher ones are retried when
    xatlas crashes. Measured on the ico sphere of jpcy/xatlas#146: no chart or pack option
    tried (max_iterations, max_chart_area, max_cost, fix_winding, blockAlign, resolution 0),
    nor jittered, rotated or cut-in-pieces copies avoid that crash; the retry is cheap and
    may help other meshes, then the object is reported."""
    co = xatlas.ChartOptions()
    if variant == 1:
        co.max_iterations = 4
    elif variant >= 2:
        co.max_chart_area = 0.5
    return co


def layout(p, tri, resolution: int, padding: int, poly, max_resolution: int = 0, variant: int = 0,
           texels_per_unit: float = 0.0) -> dict:
    """Charts, polygon fix, packing and overlap repair of one mesh (see the module docstring).

    p : (V, 3) float64, tri : (t, 3) int64, poly : (t,) int64 or None.
    max_resolution : grow the map up to this size when the charts do not fit (0: never grow).
    texels_per_unit : texel density to hold (texels per unit of ``p``); the map grows past
        ``resolution`` (up to ``max_resolution``) until the charts fit at it. 0: fit ``resolution``.

    Returns a dict: uv (t, 3, 2) float32 in [0, 1], chart (t,) int32, chart_count,
    utilization, polygons_fixed, polygons_detached, resolution (the map's side in texels).
    """
    # -- pass 1: charts (xatlas estimates texels per unit for the resolution)
    atlas = xatlas.Atlas()
    atlas.add_mesh(p.astype(np.float32), tri.astype(np.uint32))
    atlas.generate(chart_options(variant), pack_options(resolution, padding))
    xref, index, uv = atlas[0]
    index = index.astype(np.int64)
    xref = xref.astype(np.int64)
    uv_texel = uv.astype(np.float64) * [atlas.width, atlas.height]
    atlas_of_vertex, chart_of_vertex = atlas.get_mesh_vertex_assignment(0)
    charted = atlas_of_vertex.astype(np.int64) != 0xFFFFFFFF
    chart_of_vertex = np.where(charted, chart_of_vertex.astype(np.int64), -1)
    valid = charted[index].all(axis=1)  # xatlas skips degenerate triangles
    width, height, tpu, chart_count = atlas.width, atlas.height, atlas.texels_per_unit, atlas.chart_count
    if not valid.any() or width == 0 or height == 0:
        raise ValueError(f"xatlas charted none of the {len(tri)} triangles (all degenerate at float32 precision?)")

    # -- polygon fix: re-join polygons split across charts
    fixed = 0
    if poly is not None:
        index, xref, uv_texel, chart_of_vertex, fixed = _join_split_polygons(
            p, tri, poly, valid, index, xref, uv_texel, chart_of_vertex, width, height)

    # -- pass 2: repack the same charts to fit (and fill) the requested resolution
    fill = max(width, height) / resolution
    start = tpu / fill
    if texels_per_unit > 0:
        side = side_at_density(p, xref, index, uv_texel, valid, resolution, padding, texels_per_unit,
                               max_resolution)
        if side > resolution:  # start at the density: it fits and fills the grown side
            resolution, start = side, texels_per_unit
            fill = max(width, height) / resolution
        start = max(start, texels_per_unit)  # it fits: filling the map never scales the charts below it
    chart = np.where(valid, chart_of_vertex[index[:, 0]], -1)
    if fixed or fill > 1.0 or fill < GOOD_FILL or tpu < texels_per_unit:
        index, xref, uv_texel, chart_count, chart, tpu, resolution = _pack_growing(
            p, xref, index, uv_texel, valid, resolution, padding, start, max_resolution)

    # -- overlap repair: polygons folded onto others become islands, then pack again
    polygon = poly if poly is not None else np.arange(len(tri))
    detached = 0
    for _ in range(REPAIR_ROUNDS):
        uv_corner = _corner_uv(uv_texel, index, resolution, tri, valid, polygon)
        islands = _polygons_to_detach(uv_corner, polygon, resolution)
        if len(islands) == 0:
            break
        detached += len(islands)
        index, xref, uv_texel = _detach(p, tri, polygon, valid, islands, index, xref, uv_texel, tpu)
        index, xref, uv_texel, chart_count, chart, tpu, resolution = _pack_growing(
            p, xref, index, uv_texel, valid, resolution, padding, tpu, max_resolution)
    uv_corner = _corner_uv(uv_texel, index, resolution, tri, valid, polygon)
    e1 = uv_corner[:, 1] - uv_corner[:, 0]
    e2 = uv_corner[:, 2] - uv_corner[:, 0]
    utilization = float(0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])[valid].sum())
    return dict(uv=uv_corner, chart=chart.astype(np.int32), chart_count=int(chart_count),
                utilization=min(utilization, 1.0), polygons_fixed=int(fixed), polygons_detached=int(detached),
                resolution=int(resolution))


def _corner_uv(uv_texel, index, resolution, tri, valid, polygon):
    """(t, 3, 2) float32 UVs in [0, 1]: one UV per polygon corner, degenerate triangles placed."""
    uv_corner = (uv_texel[index] / resolution).astype(np.float32)  # same texel size as xatlas's atlas
    uv_corner = _place_degenerate(uv_corner, tri, valid, polygon)
    return np.clip(_one_uv_per_polygon_corner(uv_corner, tri, polygon), 0.0, 1.0)


def _one_uv_per_polygon_corner(uv_corner, tri, polygon):
    """Every corner takes the UV of the first corner with its (polygon, vertex): what
    :func:`core.unwrap.loop_uvs` will write, so overlap tests see the written layout."""
    key = polygon[:, None].astype(np.int64) * (int(tri.max(initial=0)) + 1) + tri
    _, first, inverse = np.unique(key.reshape(-1), return_index=True, return_inverse=True)
    flat = uv_corner.reshape(-1, 2)
    return flat[first][inverse].reshape(uv_corner.shape)


def _polygons_to_detach(uv_corner, polygon, resolution):
    """Polygons to move out: at every test point inside two or more polygons' triangles,
    all but the lowest-numbered polygon. The test points are the texel centres (what a Cycles
    bake samples and :func:`core.unwrap.unwrap`'s gate tests) and REPAIR_SAMPLES x REPAIR_SAMPLES
    points per texel (the bake's samples, and folds thinner than a texel): neither grid holds the
    other's points, and a fold a hundredth of a texel thick (Sponza as one object at 16 texels/m,
    round columns' cap and side triangles) covers a point of one alone."""
    found = [overlap_points(uv_corner, None, resolution, resolution, n) for n in (1, REPAIR_SAMPLES)]
    point = np.concatenate([found[0][0], found[1][0] + resolution * resolution])  # one index space per grid
    owner = np.concatenate([found[0][1], found[1][1]])
    if len(point) == 0:
        return np.zeros(0, np.int64)
    owner_poly = polygon[owner]
    order = np.lexsort((owner_poly, point))
    point, owner_poly = point[order], owner_poly[order]
    first = np.r_[True, point[1:] != point[:-1]]
    kept = np.maximum.accumulate(np.where(first, np.arange(len(point)), 0))  # each point's first entry
    return np.unique(owner_poly[owner_poly != owner_poly[kept]])


def _detach(p, tri, polygon, valid, islands, index, xref, uv_texel, tpu):
    """Give each polygon in ``islands`` fresh output vertices: its vertices projected on the
    polygon's best-fit (Newell) plane at ``tpu`` texels per unit, each island translated
    to a place of its own (xatlas joins input-UV charts at equal position and UV)."""
    index = index.copy()
    xref = list(xref)
    uv_rows = [np.asarray(uv_texel, np.float64).reshape(-1, 2)]
    offset_x = 2.0 * (uv_rows[0][:, 0].max(initial=0.0) + 1.0)
    members = np.flatnonzero(np.isin(polygon, islands) & valid)
    members = members[np.argsort(polygon[members], kind="stable")]
    next_vertex = len(xref)
    for group in np.split(members, np.flatnonzero(np.diff(polygon[members])) + 1):
        if len(group) == 0:
            continue
        corners = p[tri[group]]
        normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]).sum(axis=0)
        u_axis, v_axis = _plane_basis(normal)
        verts, local = np.unique(tri[group].reshape(-1), return_inverse=True)
        uv = np.stack([p[verts] @ u_axis, p[verts] @ v_axis], axis=1) * tpu
        uv -= uv.min(axis=0)
        uv[:, 0] += offset_x
        offset_x += float(uv[:, 0].max()) + 8.0
        index[group] = next_vertex + local.reshape(-1, 3)
        next_vertex += len(verts)
        xref.extend(int(v) for v in verts)
        uv_rows.append(uv)
    return index, np.asarray(xref, np.int64), np.concatenate(uv_rows)


def _plane_basis(normal):
    """Two orthonormal axes spanning the plane with ``normal`` (any basis for a zero normal)."""
    length = float(np.linalg.norm(normal))
    n = normal / length if length > 0 else np.array([0.0, 0.0, 1.0])
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


def side_at_density(p, xref, index, uv_texel, valid, resolution: int, padding: int, texels_per_unit: float,
                    max_resolution: int) -> int:
    """The map's side that holds the charts at ``texels_per_unit`` (one xatlas packing of any
    size), rounded up to 4 texels: at least ``resolution``, at most ``max(max_resolution,
    resolution)`` (past that the charts are scaled down to fit, as without a density)."""
    atlas = _pack(p, xref, index, uv_texel, valid, padding, texels_per_unit)
    needed = 4 * math.ceil(max(atlas.width, atlas.height) / 4)
    return int(min(max(needed, resolution), max(max_resolution, resolution)))


def _pack(p, xref, index, uv_texel, valid, padding: int, texels_per_unit: float) -> "xatlas.Atlas":
    """The charts packed again (xatlas ``use_input_mesh_uvs``) at ``texels_per_unit`` into one
    atlas of whatever size they need."""
    atlas = xatlas.Atlas()
    atlas.add_mesh(p[xref].astype(np.float32), index[valid].astype(np.uint32), None, uv_texel.astype(np.float32))
    chart_options = xatlas.ChartOptions()
    chart_options.use_input_mesh_uvs = True
    atlas.generate(chart_options, pack_options(0, padding, texels_per_unit))  # 0: one atlas, any size
    return atlas


def _pack_growing(p, xref, index, uv_texel, valid, resolution, padding, tpu, max_resolution):
    """:func:`_repack` at ``resolution``, growing the map by :data:`GROWTH` up to
    ``max_resolution`` while the charts do not fit. Returns (index, xref, uv_texel,
    chart_count, chart, texels per unit, resolution)."""
    while True:
        try:
            out = _repack(p, xref, index, uv_texel, valid, resolution, padding, tpu)
            return (*out, resolution)
        except PackError as e:
            if resolution >= max_resolution:
                raise PackError(f"{e}; the largest allowed map is {max(max_resolution, resolution)}x"
                                f"{max(max_resolution, resolution)}", e.minimum) from None
            grown = min(4 * math.ceil(resolution * GROWTH / 4), max_resolution)
            tpu *= grown / resolution
            resolution = grown


def pack_options(resolution: int, padding: int, texels_per_unit: float = 0.0) -> "xatlas.PackOptions":
    """xatlas's packing: ``padding`` texels between charts, for bilinear filtering, without block
    alignment. Aligned to 4x4 blocks, xatlas scales small charts unevenly: at 4 texels/m (272^2) 8.4 %
    of the bench's occluded building mapped to texels more than twice as long one way as the other
    (5.2 % without; 0.3 % against 0 at 1024^2) and Sponza at 796^2 2.9 % (0.7 % without), where a
    texel 0.55 m long and 2.7 cm wide on a slab's edge averaged light that changes along it. And each
    small chart took a 4x4 block: a 6 m floor among 64 posts of 5 cm, fitted to the map its area asks at
    16 texels per unit, got 3.2 of them (15 without; tests/test_unwrap.py). Sponza's utilization without:
    0.402 -> 0.424 at 796^2, 0.612 -> 0.623 at 1388^2, 0.716 -> 0.656 at 2048^2 (its densest map)."""
    po = xatlas.PackOptions()
    po.resolution = resolution
    po.padding = padding
    po.bilinear = True
    po.blockAlign = False
    po.texels_per_unit = texels_per_unit
    return po


def _repack(p, xref, index, uv_texel, valid, resolution, padding, tpu):
    """Pack the given charts again (xatlas ``use_input_mesh_uvs``) so the atlas fits
    ``resolution`` squared; returns (index, xref, uv_texel, chart_count, chart, texels per unit)
    with UVs in texels of ``resolution``. Raises :class:`PackError` if no scale fits."""
    # Search texels-per-unit: the largest tried that fits, stopping once the atlas
    # fills >= GOOD_FILL of the side. Packing size is not linear in the scale
    # (padding and the least chart size are fixed), hence a search, not one rescale.
    best, best_tpu, fits, too_big = None, 0.0, None, None
    for _ in range(MAX_PACK_ATTEMPTS):
        atlas = _pack(p, xref, index, uv_texel, valid, padding, tpu)
        size = max(atlas.width, atlas.height)
        if size <= resolution:
            if tpu > best_tpu:
                best, best_tpu = atlas, tpu
            fits = tpu
            if size >= GOOD_FILL * resolution or (too_big is not None and too_big / fits < 1.01):
                break
        else:
            too_big = tpu
        if fits is None:
            tpu *= (resolution / size) ** 1.5 * 0.98
        elif too_big is None:
            tpu *= resolution / size
        else:
            tpu = math.sqrt(fits * too_big)
    if best is None:
        raise PackError(f"xatlas could not pack the charts into {resolution}x{resolution} "
                        f"with padding {padding} after {MAX_PACK_ATTEMPTS} attempts")
    xref2, index2, uv2 = best[0]
    # xatlas keeps face order: pass-2 face k is the k-th valid triangle.
    new_index = np.zeros_like(index)
    new_index[valid] = index2.astype(np.int64)
    uv2_texel = uv2.astype(np.float64) * [best.width, best.height]
    chart = np.full(len(index), -1, np.int64)
    chart[valid] = best.get_mesh_vertex_assignment(0)[1].astype(np.int64)[index2[:, 0]]
    return new_index, np.asarray(xref)[xref2.astype(np.int64)], uv2_texel, best.chart_count, chart, best_tpu


def _join_split_polygons(p, tri, poly, valid, index, xref, uv_texel, chart_of_vertex, width, height):
    """Re-join polygons whose triangles xatlas put in different charts.

    A polygon is split when one of its vertices has two different xatlas output
    vertices (two UVs) among its triangles. For each such polygon the chart with
    the largest share of the polygon's area keeps its triangles; the others are
    unfolded into that chart across the edges they share with placed triangles,
    keeping their 3-D shape at the chart's local scale and the chart's winding.
    An unfolded corner whose vertex already has a UV in that chart reuses it.
    If an unfolded triangle then overlaps another triangle (checked by
    rasterising at 8x8 points per texel), the whole polygon is detached as an
    island of its own instead. Pass 2 then repacks, so grown charts and new
    islands cannot overlap other charts. Known limit: overlaps thinner than
    1/8 texel can slip through (seen on 2 of 3200 triangles of a quad grid with
    random heights; none on smooth surfaces).

    Returns (index, xref, uv_texel, chart_of_vertex, polygons_fixed).
    """
    from .raster import overlapping

    corners = np.flatnonzero(np.repeat(valid, 3))
    key_poly = poly[corners // 3]
    key_vert = tri.reshape(-1)[corners]
    out_vert = index.reshape(-1)[corners]
    order = np.lexsort((out_vert, key_vert, key_poly))
    kp, kv, ko = key_poly[order], key_vert[order], out_vert[order]
    differ = (kp[1:] == kp[:-1]) & (kv[1:] == kv[:-1]) & (ko[1:] != ko[:-1])
    split_polys = np.unique(kp[1:][differ])
    if len(split_polys) == 0:
        return index, xref, uv_texel, chart_of_vertex, 0

    layout = _Layout(p, tri, index, xref, uv_texel, chart_of_vertex)
    area = 0.5 * np.linalg.norm(np.cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]]), axis=1)
    members = np.flatnonzero(np.isin(poly, split_polys) & valid)
    members = members[np.argsort(poly[members], kind="stable")]
    groups = np.split(members, np.flatnonzero(np.diff(poly[members])) + 1)

    # -- unfold each split polygon into its majority chart
    plans = []
    for group in groups:
        group = [int(k) for k in group]
        charts = [int(chart_of_vertex[index[k, 0]]) for k in group]
        share: dict = {}
        for k, c in zip(group, charts):
            share[c] = share.get(c, 0.0) + area[k]
        target = max(share, key=share.get)
        anchor = max((k for k, c in zip(group, charts) if c == target), key=lambda k: area[k])
        plans.append((group, anchor, target))
        layout.unfold(group, anchor, target, reuse=True)

    # -- detach polygons whose unfolded triangles overlap something
    moved = np.zeros(len(tri), bool)
    moved[members] = True
    uv_unit = (layout.uv()[layout.index] / [width, height]).astype(np.float32)
    candidates = _near(uv_unit, valid, moved, width, height)
    bad = np.zeros(len(tri), bool)
    bad[candidates] = overlapping(uv_unit[candidates], width, height, 8)
    bad_polys = set(poly[bad & moved].tolist())
    for group, anchor, target in plans:
        if int(poly[group[0]]) in bad_polys:
            layout.unfold(group, anchor, -1, reuse=False)
    return layout.index, layout.xref(), layout.uv(), layout.chart(), len(groups)


def _near(uv_unit, valid, moved, width, height):
    """Valid triangles whose texel bounding box meets that of a moved triangle."""
    lo = np.floor(uv_unit.min(1) * [width, height]).astype(np.int64) - 1
    hi = np.floor(uv_unit.max(1) * [width, height]).astype(np.int64) + 1
    lo = np.clip(lo, 0, [width - 1, height - 1])
    hi = np.clip(hi, 0, [width - 1, height - 1])
    marked = np.zeros((height + 1, width + 1), np.int64)  # 2-D difference array of moved boxes
    m = np.flatnonzero(moved)
    np.add.at(marked, (lo[m, 1], lo[m, 0]), 1)
    np.add.at(marked, (lo[m, 1], hi[m, 0] + 1), -1)
    np.add.at(marked, (hi[m, 1] + 1, lo[m, 0]), -1)
    np.add.at(marked, (hi[m, 1] + 1, hi[m, 0] + 1), 1)
    covered = np.cumsum(np.cumsum(marked, 0), 1)[:height, :width] > 0
    table = np.zeros((height + 1, width + 1), np.int64)  # summed-area table of covered texels
    table[1:, 1:] = np.cumsum(np.cumsum(covered, 0), 1)
    hits = (table[hi[:, 1] + 1, hi[:, 0] + 1] - table[lo[:, 1], hi[:, 0] + 1]
            - table[hi[:, 1] + 1, lo[:, 0]] + table[lo[:, 1], lo[:, 0]])
    return np.flatnonzero(valid & (hits > 0))


class _Layout:
    """Pass-1 UV layout being edited: corner -> output vertex, output vertex -> (input vertex, uv, chart)."""

    def __init__(self, p, tri, index, xref, uv_texel, chart_of_vertex):
        self.p, self.tri = p, tri
        self.index = index.copy()
        self._xref = [int(v) for v in xref]
        self._uv = [np.asarray(u, np.float64) for u in uv_texel]
        self._chart = [int(c) for c in chart_of_vertex]
        self._original = index.copy()
        self.by_vertex_chart: dict = {}
        for o, (v, c) in enumerate(zip(self._xref, self._chart)):
            if c >= 0:
                self.by_vertex_chart.setdefault((v, c), []).append(o)
        self._next_chart = max(self._chart, default=-1) + 1
        uv = np.asarray(uv_texel, np.float64).reshape(-1, 2)
        self.island_offset = np.array([2.0 * (uv[:, 0].max(initial=0.0) + 1.0), 0.0])

    def xref(self):
        return np.asarray(self._xref, np.int64)

    def uv(self):
        return np.asarray(self._uv, np.float64).reshape(-1, 2)

    def chart(self):
        return np.asarray(self._chart, np.int64)

    def _new_vertex(self, v, uv, chart):
        self._xref.append(v)
        self._uv.append(np.asarray(uv, np.float64))
        self._chart.append(chart)
        o = len(self._xref) - 1
        self.by_vertex_chart.setdefault((v, chart), []).append(o)
        return o

    def unfold(self, group, anchor, target, reuse):
        """Lay the triangles of one polygon out around ``anchor`` (its pass-1 UVs kept).

        reuse=True: into chart ``target``, sharing the chart's vertices.
        reuse=False: as a new island (fresh vertices, a new chart id).
        """
        a_uv = [self._uv[int(o)] for o in self._original[anchor]]
        winding = np.sign(_cross2(a_uv[1] - a_uv[0], a_uv[2] - a_uv[0]))
        if reuse:
            known = {int(v): int(o) for v, o in zip(self.tri[anchor], self._original[anchor])}
        else:
            target = self._next_chart
            self._next_chart += 1
            # Away from every chart: xatlas joins input-UV charts at vertices with equal
            # position and UV, so the island must not reuse the anchor's UVs verbatim.
            a_uv = [u + self.island_offset for u in a_uv]
            known = {int(v): self._new_vertex(int(v), u, target) for v, u in zip(self.tri[anchor], a_uv)}
        self.index[anchor] = [known[int(v)] for v in self.tri[anchor]]
        pending = [k for k in group if k != anchor]
        progress = True
        while pending and progress:
            progress = False
            for k in list(pending):
                verts = [int(v) for v in self.tri[k]]
                have = [v in known for v in verts]
                if sum(have) < 2:
                    continue
                if not all(have):
                    j = have.index(False)  # the corner to unfold across the opposite edge
                    o = int(self._original[k, j])
                    if reuse and self._chart[o] == target:  # already in the chart: keep its UV
                        known[verts[j]] = o
                        self.index[k] = [known[v] for v in verts]
                        pending.remove(k)
                        progress = True
                        continue
                    q = self._unfold_corner(verts, j, known, winding)
                    if q is None:
                        continue
                    known[verts[j]] = self._place(verts[j], q, target, reuse)
                self.index[k] = [known[v] for v in verts]
                pending.remove(k)
                progress = True

    def _unfold_corner(self, verts, j, known, winding):
        i0, i1 = (j + 1) % 3, (j + 2) % 3
        u0, u1 = self._uv[known[verts[i0]]], self._uv[known[verts[i1]]]
        p0, p1, pj = self.p[verts[i0]], self.p[verts[i1]], self.p[verts[j]]
        edge = p1 - p0
        length = float(np.linalg.norm(edge))
        e_uv = u1 - u0
        l_uv = float(np.hypot(*e_uv))
        if length <= 0 or l_uv <= 0:
            return None  # collapsed edge: cannot unfold across it
        x = float(np.dot(pj - p0, edge)) / length  # 3-D triangle in the edge's frame
        y = float(np.linalg.norm(np.cross(pj - p0, edge))) / length
        t_hat = e_uv / l_uv
        n_hat = np.array([-t_hat[1], t_hat[0]])
        scale = l_uv / length  # the chart's texels per unit along this edge
        for sign in (1.0, -1.0):
            q = u0 + scale * (x * t_hat + sign * y * n_hat)
            c = {i0: u0, i1: u1, j: q}
            if np.sign(_cross2(c[1] - c[0], c[2] - c[0])) == winding:
                return q
        return u0 + scale * x * t_hat

    def _place(self, v, q, target, reuse):
        if reuse:  # the chart's own UV of that vertex, if it is where the unfolding puts it
            for o in self.by_vertex_chart.get((v, target), []):
                if np.hypot(*(self._uv[o] - q)) < 0.25:
                    return o
        return self._new_vertex(v, q, target)


def _cross2(a, b):
    return a[0] * b[1] - a[1] * b[0]


def _place_degenerate(uv_corner, tri, valid, polygon):
    """UVs for the corners of triangles xatlas skipped (zero area in 3-D), kept inside their
    own polygon so they cover no texel another triangle covers.

    A corner takes the UV its vertex has in a charted triangle of the same polygon; a corner
    whose vertex has none (the middle vertex of a collinear triangle) takes the UV of the
    triangle's first placed corner (the triangle has zero UV area, as in 3-D); a polygon with
    no charted triangle collapses to one point: the UV one of its vertices has elsewhere,
    else (0, 0). UVs from *other* polygons are never mixed into one triangle: they may lie
    in another chart, and the triangle would then span the map across other charts.
    """
    if valid.all():
        return uv_corner
    uv_corner = uv_corner.copy()
    invalid = np.flatnonzero(~valid)
    good = np.flatnonzero(valid)
    near = good[np.isin(polygon[good], polygon[invalid])]
    polygon_vertex_uv, polygon_uv = {}, {}
    for k in near[::-1]:  # first triangle wins
        polygon_uv[int(polygon[k])] = uv_corner[k, 0]
        for v, u in zip(tri[k], uv_corner[k]):
            polygon_vertex_uv[(int(polygon[k]), int(v))] = u
    vertex_uv = {}
    lonely = set(polygon[invalid].tolist()) - set(polygon[near].tolist())
    if lonely:
        for k in good[::-1]:
            for v, u in zip(tri[k], uv_corner[k]):
                vertex_uv[int(v)] = u
    point_of_polygon = {}
    for k in invalid:
        f = int(polygon[k])
        if f in lonely:
            if f not in point_of_polygon:
                found = [vertex_uv.get(int(v)) for v in tri[k]]
                point_of_polygon[f] = next((u for u in found if u is not None), np.zeros(2, np.float32))
            uv_corner[k] = point_of_polygon[f]
            continue
        found = [polygon_vertex_uv.get((f, int(v))) for v in tri[k]]
        # no corner in the polygon's charts: a point of the polygon
        fallback = next((u for u in found if u is not None), polygon_uv[f])
        for j, v in enumerate(tri[k]):
            u = found[j] if found[j] is not None else fallback
            polygon_vertex_uv[(f, int(v))] = u  # later triangles with this corner agree
            uv_corner[k, j] = u
    return uv_corner
