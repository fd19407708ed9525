"""Light-map UVs: choose a resolution, unwrap with xatlas, map UVs back to polygon corners.

Every baked object needs a second UV map whose charts do not overlap and sit
``padding`` texels apart, so each texel belongs to one piece of surface. This
module wraps xatlas (``xatlas`` 0.0.11, the Python binding of jpcy/xatlas):

1. **Pass 1, charting.** xatlas segments the triangles into charts,
   parametrises and packs them (``ChartOptions`` defaults; ``PackOptions`` with
   ``resolution``, ``padding``, ``bilinear=True``, ``blockAlign=True``). This is
   the slow step (~7 s for a 65k-triangle grid) and is why results are cached.
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
   ``padding`` texels and texels stay square.

UVs follow Blender: u to the right, v up, in [0, 1].
"""
from __future__ import annotations

import hashlib
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import xatlas

# Bump when anything here changes the UVs produced for the same input (cache key).
ALGORITHM_VERSION = 1
# Pass-2 repacking: at most this many packings to fit the requested resolution.
MAX_PACK_ATTEMPTS = 10
# Pass 2 is skipped when pass 1's atlas already fits and fills at least this much of it.
GOOD_FILL = 0.95


# --------------------------------------------------------------------------- resolution
def choose_resolution(surface_area: float, texel_density: float, default_resolution: int,
                      min_resolution: int, max_resolution: int) -> int:
    """Light-map width (= height) in texels for an object.

    Parameters
    ----------
    surface_area : total surface area of the object, scene units squared.
    texel_density : texels per scene unit; 0 means "use ``default_resolution``".
        Typical 8-64 for metre-scale scenes.
    default_resolution : resolution when ``texel_density`` is 0 (typical 256).
    min_resolution, max_resolution : clamp of the density-derived resolution.

    Returns
    -------
    int : ``default_resolution`` if the density is 0, else
        ``ceil(sqrt(surface_area) * texel_density)`` rounded up to a multiple of 4
        (xatlas aligns charts to 4x4 blocks) and clamped to [min, max].
    """
    if not (math.isfinite(surface_area) and math.isfinite(texel_density)):
        raise ValueError(f"choose_resolution: non-finite surface area {surface_area!r} or texel density {texel_density!r}")
    if texel_density < 0 or surface_area < 0:
        raise ValueError(f"choose_resolution: negative surface area {surface_area!r} or texel density {texel_density!r}")
    if min_resolution > max_resolution:
        raise ValueError(f"choose_resolution: min_resolution {min_resolution} > max_resolution {max_resolution}")
    if texel_density == 0:
        return int(default_resolution)
    texels = math.ceil(math.sqrt(surface_area) * texel_density)
    texels = 4 * math.ceil(texels / 4)
    return int(min(max(texels, min_resolution), max_resolution))


# --------------------------------------------------------------------------- result
@dataclass(frozen=True)
class UnwrapResult:
    """Light-map UVs of one object.

    uv : (t, 3, 2) float32 per-triangle-corner UVs in [0, 1] (u right, v up),
        triangles in input order. A degenerate (zero-area) triangle, which xatlas
        leaves out of every chart, gets the UVs its vertices have in other
        triangles (its own polygon's first), so it is a sliver or a point inside
        a chart; a degenerate triangle none of whose vertices is charted collapses
        to the point (0, 0).
    chart_count : number of charts.
    utilization : fraction of the [0, 1]^2 square covered by UV triangles (0..1,
        typical 0.5-0.8).
    from_cache : True if read from ``cache_dir`` instead of computed.
    polygons_fixed : number of polygons xatlas split across charts that were
        re-joined (0 when no polygon structure was given).
    chart : (t,) int32 chart of each triangle, -1 for degenerate triangles.
    """

    uv: np.ndarray
    chart_count: int
    utilization: float
    from_cache: bool = False
    polygons_fixed: int = 0
    chart: np.ndarray | None = None


def cache_key(positions: np.ndarray, triangles: np.ndarray, resolution: int, padding: int,
              triangle_polygon: np.ndarray | None = None) -> str:
    """sha256 (hex) of everything the UVs depend on: geometry, polygons, resolution,
    padding, the xatlas version and :data:`ALGORITHM_VERSION`."""
    h = hashlib.sha256()
    h.update(b"pdic-unwrap\0")
    h.update(np.ascontiguousarray(positions, dtype=np.float64).tobytes())
    h.update(b"\0")
    h.update(np.ascontiguousarray(triangles, dtype=np.int64).tobytes())
    h.update(b"\0")
    if triangle_polygon is not None:
        h.update(np.ascontiguousarray(triangle_polygon, dtype=np.int64).tobytes())
    h.update(f"\0{int(resolution)}\0{int(padding)}\0{xatlas.__version__}\0{ALGORITHM_VERSION}".encode())
    return h.hexdigest()


# --------------------------------------------------------------------------- unwrap
def unwrap(positions: np.ndarray, triangles: np.ndarray, resolution: int, padding: int,
           cache_dir: Path | None = None, triangle_polygon: np.ndarray | None = None) -> UnwrapResult:
    """Unwrap a mesh into non-overlapping light-map charts.

    Parameters
    ----------
    positions : (V, 3) float64 vertex positions (any consistent space; object-local
        keeps the cache valid when the object moves).
    triangles : (t, 3) int vertex indices; output keeps this order.
    resolution : light-map width and height in texels (typical 64-2048).
    padding : texels of gutter between charts (typical 2).
    cache_dir : folder for content-keyed ``unwrap-<sha256>.npz`` files, or None.
    triangle_polygon : (t,) int, optional polygon (Blender face) of each triangle,
        e.g. ``MeshLoopTriangle.polygon_index``. When given, polygons that xatlas
        split across charts are re-joined so each polygon corner has one UV
        (see :func:`loop_uvs`).

    Returns
    -------
    UnwrapResult

    Raises
    ------
    ValueError : on non-finite positions, indices out of range, bad shapes or a
        resolution/padding that leaves no room.
    """
    p = np.ascontiguousarray(positions, dtype=np.float64)
    tri = np.ascontiguousarray(triangles)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"unwrap: positions must be (V, 3), got {p.shape}")
    if tri.ndim != 2 or tri.shape[1] != 3 or (tri.size and not np.issubdtype(tri.dtype, np.integer)):
        raise ValueError(f"unwrap: triangles must be (t, 3) integers, got {tri.shape} {tri.dtype}")
    tri = tri.astype(np.int64)
    if not np.isfinite(p).all():
        bad = np.flatnonzero(~np.isfinite(p).all(axis=1))
        raise ValueError(f"unwrap: {len(bad)} vertex positions are non-finite (NaN or inf), first vertex {bad[0]}")
    if tri.size and (tri.min() < 0 or tri.max() >= len(p)):
        raise ValueError(f"unwrap: triangle indices out of range [0, {len(p)})")
    if resolution < 1 or padding < 0 or 2 * padding >= resolution:
        raise ValueError(f"unwrap: resolution {resolution} with padding {padding} leaves no room for charts")
    poly = None
    if triangle_polygon is not None:
        poly = np.ascontiguousarray(triangle_polygon, dtype=np.int64)
        if poly.shape != (len(tri),):
            raise ValueError(f"unwrap: triangle_polygon must be ({len(tri)},), got {poly.shape}")

    # -- content-keyed cache (STYLE principle 8)
    path = None
    if cache_dir is not None:
        path = Path(cache_dir) / f"unwrap-{cache_key(p, tri, resolution, padding, poly)}.npz"
        cached = _load(path, len(tri))
        if cached is not None:
            return cached

    if len(tri) == 0:
        result = UnwrapResult(np.zeros((0, 3, 2), np.float32), 0, 0.0, chart=np.zeros(0, np.int32))
    else:
        result = _unwrap(p, tri, int(resolution), int(padding), poly)

    if path is not None:
        _store(path, result)
    return result


def _pack_options(resolution: int, padding: int, texels_per_unit: float = 0.0) -> "xatlas.PackOptions":
    po = xatlas.PackOptions()
    po.resolution = resolution
    po.padding = padding
    po.bilinear = True
    po.blockAlign = True
    po.texels_per_unit = texels_per_unit
    return po


def _unwrap(p, tri, resolution, padding, poly) -> UnwrapResult:
    # -- pass 1: charts (xatlas estimates texels per unit for the resolution)
    atlas = xatlas.Atlas()
    atlas.add_mesh(p.astype(np.float32), tri.astype(np.uint32))
    atlas.generate(xatlas.ChartOptions(), _pack_options(resolution, padding))
    xref, index, uv = atlas[0]
    index = index.astype(np.int64)
    xref = xref.astype(np.int64)
    uv_texel = uv.astype(np.float64) * [atlas.width, atlas.height]
    atlas_of_vertex, chart_of_vertex = atlas.get_mesh_vertex_assignment(0)
    charted = atlas_of_vertex.astype(np.int64) != 0xFFFFFFFF
    chart_of_vertex = np.where(charted, chart_of_vertex.astype(np.int64), -1)
    valid = charted[index].all(axis=1)  # xatlas skips degenerate triangles
    width, height, tpu, chart_count = atlas.width, atlas.height, atlas.texels_per_unit, atlas.chart_count

    # -- polygon fix: re-join polygons split across charts
    fixed = 0
    if poly is not None:
        index, xref, uv_texel, chart_of_vertex, fixed = _join_split_polygons(
            p, tri, poly, valid, index, xref, uv_texel, chart_of_vertex, width, height)

    # -- pass 2: repack the same charts to fit (and fill) the requested resolution
    fill = max(width, height) / resolution
    chart = np.where(valid, chart_of_vertex[index[:, 0]], -1)
    if fixed or fill > 1.0 or fill < GOOD_FILL:
        index, uv_texel, width, height, chart_count, chart = _repack(
            p, xref, index, uv_texel, valid, resolution, padding, tpu / fill)

    uv_corner = (uv_texel[index] / resolution).astype(np.float32)  # same texel size as xatlas's atlas
    uv_corner = _place_degenerate(uv_corner, tri, valid, poly)
    uv_corner = np.clip(uv_corner, 0.0, 1.0)
    e1 = uv_corner[:, 1] - uv_corner[:, 0]
    e2 = uv_corner[:, 2] - uv_corner[:, 0]
    utilization = float(0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])[valid].sum())
    return UnwrapResult(uv_corner, int(chart_count), min(utilization, 1.0), False, fixed, chart.astype(np.int32))


def _repack(p, xref, index, uv_texel, valid, resolution, padding, tpu):
    """Pack the given charts again (xatlas ``use_input_mesh_uvs``) so the atlas fits
    ``resolution`` squared; returns (index, uv_texel, width, height, chart_count, chart)."""
    positions = p[xref].astype(np.float32)
    uvs = uv_texel.astype(np.float32)
    faces = index[valid].astype(np.uint32)
    chart_options = xatlas.ChartOptions()
    chart_options.use_input_mesh_uvs = True
    # Search texels-per-unit: the largest tried that fits, stopping once the atlas
    # fills >= GOOD_FILL of the side. Packing size is not linear in the scale
    # (padding and 4x4 block alignment are fixed), hence a search, not one rescale.
    best, best_tpu, fits, too_big = None, 0.0, None, None
    for _ in range(MAX_PACK_ATTEMPTS):
        atlas = xatlas.Atlas()
        atlas.add_mesh(positions, faces, None, uvs)
        atlas.generate(chart_options, _pack_options(0, padding, tpu))  # 0: one atlas, any size
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
        raise RuntimeError(f"unwrap: xatlas could not pack the charts into {resolution}x{resolution} "
                           f"with padding {padding} after {MAX_PACK_ATTEMPTS} attempts")
    xref2, index2, uv2 = best[0]
    # xatlas keeps face order: pass-2 face k is the k-th valid triangle.
    new_index = np.zeros_like(index)
    new_index[valid] = index2.astype(np.int64)
    uv2_texel = uv2.astype(np.float64) * [best.width, best.height]
    chart = np.full(len(index), -1, np.int64)
    chart[valid] = best.get_mesh_vertex_assignment(0)[1].astype(np.int64)[index2[:, 0]]
    return new_index, uv2_texel, best.width, best.height, best.chart_count, chart


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


def _place_degenerate(uv_corner, tri, valid, poly):
    """Give corners of triangles xatlas skipped the UV their vertex has elsewhere
    (in the same polygon first), else their triangle's first placed corner, else (0, 0)."""
    if valid.all():
        return uv_corner
    uv_corner = uv_corner.copy()
    invalid = np.flatnonzero(~valid)
    good = np.flatnonzero(valid)
    vertex_uv = {}
    for k in good[::-1]:  # first triangle wins
        for v, u in zip(tri[k], uv_corner[k]):
            vertex_uv[int(v)] = u
    poly_vertex_uv = {}
    if poly is not None:
        for k in good[np.isin(poly[good], poly[invalid])][::-1]:
            for v, u in zip(tri[k], uv_corner[k]):
                poly_vertex_uv[(int(poly[k]), int(v))] = u
    for k in invalid:
        found = [poly_vertex_uv.get((int(poly[k]), int(v))) if poly is not None else None for v in tri[k]]
        found = [f if f is not None else vertex_uv.get(int(v)) for f, v in zip(found, tri[k])]
        fallback = next((f for f in found if f is not None), np.zeros(2, np.float32))
        uv_corner[k] = [f if f is not None else fallback for f in found]
    return uv_corner


# --------------------------------------------------------------------------- polygon corners
def loop_uvs(uv_corner: np.ndarray, triangle_loops: np.ndarray, loop_count: int,
             tolerance: float = 1e-6) -> tuple[np.ndarray, int]:
    """One UV per Blender loop (polygon corner) from per-triangle-corner UVs.

    Parameters
    ----------
    uv_corner : (t, 3, 2) float32 UVs of each loop triangle's corners.
    triangle_loops : (t, 3) int loop index of each corner (``MeshLoopTriangle.loops``).
    loop_count : number of loops of the mesh.
    tolerance : UV distance (in [0, 1] units) above which two UVs of a loop differ.

    Returns
    -------
    uv_loop : (loop_count, 2) float32; the UV of the first triangle corner using the
        loop; loops no triangle uses get (0, 0).
    conflicts : number of loops whose triangles gave UVs farther apart than
        ``tolerance`` (a polygon split across charts); 0 after :func:`unwrap`
        with ``triangle_polygon``.
    """
    uv = np.asarray(uv_corner, dtype=np.float32).reshape(-1, 2)
    loops = np.asarray(triangle_loops, dtype=np.int64).reshape(-1)
    if len(uv) != len(loops):
        raise ValueError(f"loop_uvs: {len(uv) // 3} UV triangles for {len(loops) // 3} loop triangles")
    if len(loops) and (loops.min() < 0 or loops.max() >= loop_count):
        raise ValueError(f"loop_uvs: loop index out of range [0, {loop_count})")
    uv_loop = np.zeros((loop_count, 2), np.float32)
    uv_loop[loops[::-1]] = uv[::-1]  # fancy assignment keeps the last write: reversed = first corner wins
    deviation = np.abs(uv - uv_loop[loops]).max(axis=1) if len(uv) else np.zeros(0)
    conflicts = len(np.unique(loops[deviation > tolerance]))
    return uv_loop, int(conflicts)


# --------------------------------------------------------------------------- cache files
def _load(path: Path, triangle_count: int) -> UnwrapResult | None:
    try:
        with np.load(path) as data:
            uv = data["uv"].astype(np.float32)
            chart = data["chart"].astype(np.int32)
            result = UnwrapResult(uv, int(data["chart_count"]), float(data["utilization"]), True,
                                  int(data["polygons_fixed"]), chart)
    except (OSError, KeyError, ValueError):
        return None  # missing or unreadable: recompute
    if uv.shape != (triangle_count, 3, 2) or chart.shape != (triangle_count,) or not np.isfinite(uv).all():
        return None
    return result


def _store(path: Path, result: UnwrapResult) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".unwrap-", suffix=".npz", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, uv=result.uv, chart_count=result.chart_count, utilization=result.utilization,
                     polygons_fixed=result.polygons_fixed, chart=result.chart)
        os.replace(tmp, path)  # atomic: a concurrent reader sees the old file or the whole new one
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
