"""Light-map unwrapping: resolution choice, chart layout, polygon corners, cache."""
from __future__ import annotations

import numpy as np
import pytest

from pdic.core.raster import overlapping, rasterize
from pdic.core.unwrap import achieved_texel_density, choose_resolution, loop_uvs, unwrap


def quad_grid(n, height_fn):
    """n x n quads on the unit square with z = height_fn(x, y).

    Returns positions (V, 3), triangles (2n^2, 3), triangle_polygon (2n^2,),
    triangle_loops (2n^2, 3) with loops 4q..4q+3 = corners a, b, c, d of quad q.
    """
    xs = np.linspace(0.0, 1.0, n + 1)
    x, y = np.meshgrid(xs, xs)
    positions = np.stack([x, y, height_fn(x, y)], -1).reshape(-1, 3)
    i = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).reshape(-1)
    a, b, c, d = i, i + 1, i + n + 2, i + n + 1
    triangles = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)])
    q = np.arange(n * n)
    polygon = np.concatenate([q, q])
    loops = np.concatenate([np.stack([4 * q, 4 * q + 1, 4 * q + 2], -1), np.stack([4 * q, 4 * q + 2, 4 * q + 3], -1)])
    return positions, triangles, polygon, loops


def wavy(x, y):
    return 0.2 * np.sin(8 * x) * np.cos(7 * y)


def chart_coverages_are_disjoint(result, resolution):
    owner = np.zeros((resolution, resolution), int)
    for c in np.unique(result.chart[result.chart >= 0]):
        s = rasterize(result.uv[result.chart == c], resolution, resolution)
        owner += s.coverage
    return owner.max() <= 1


# --------------------------------------------------------------------------- resolution
def test_zero_density_uses_default_resolution():
    assert choose_resolution(123.0, 0.0, 256, 16, 4096) == 256


def test_density_resolution_is_rounded_up_to_multiple_of_four_and_clamped():
    assert choose_resolution(100.0, 10.0, 256, 16, 4096) == 100  # sqrt(100) * 10
    assert choose_resolution(101.0, 10.0, 256, 16, 4096) == 104  # 100.5 -> 101 -> 104
    assert choose_resolution(0.01, 10.0, 256, 16, 4096) == 16
    assert choose_resolution(1e6, 64.0, 256, 16, 4096) == 4096


def floor_with_posts(posts: int = 24):
    """A 6 m x 6 m floor (two triangles) and ``posts`` separate 5 cm cubes on it: each cube face
    becomes a chart of a texel or two plus its gutter, as a building's railings and thin walls do."""
    verts = [(0, 0, 0), (6, 0, 0), (6, 6, 0), (0, 6, 0)]
    tris = [(0, 1, 2), (0, 2, 3)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    for k in range(posts):
        x, y, base = 0.5 + 0.7 * (k % 8), 0.5 + 0.7 * (k // 8), len(verts)
        verts += [(x + 0.05 * (i >> 2 & 1), y + 0.05 * (i >> 1 & 1), 0.05 * (i & 1)) for i in range(8)]
        for a, b, c, d in faces:
            tris += [(base + a, base + b, base + c), (base + a, base + c, base + d)]
    return np.asarray(verts, np.float64), np.asarray(tris, np.int64)


def triangle_densities(result, positions, triangles):
    """Texels per unit of each triangle of an unwrap: sqrt(UV area in texels / world area)."""
    uv = result.uv.astype(np.float64) * result.resolution
    t = positions[triangles]
    world = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    texels = 0.5 * np.abs(np.cross(uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]))
    return np.sqrt(texels / world)


def test_a_texel_density_is_held_by_growing_the_map():
    """Sized from the surface area alone, the map cannot hold many small charts with their gutters:
    fitted into it, every chart is scaled down and the floor gets less than the density asked (15 of
    16 texels per unit; 3.2 with charts aligned to 4x4 blocks, as xatlas packed them before).
    With ``texels_per_unit`` the map grows until the charts fit at the density, up to the largest
    allowed map."""
    p, t = floor_with_posts()
    density = 16.0
    t_world = p[t]
    area = 0.5 * np.linalg.norm(np.cross(t_world[:, 1] - t_world[:, 0], t_world[:, 2] - t_world[:, 0]), axis=1).sum()
    res = choose_resolution(area, density, 256, 16, 4096)
    fitted = unwrap(p, t, res, 2, max_resolution=4096)
    assert fitted.resolution == res
    assert triangle_densities(fitted, p, t)[:2].max() < 0.97 * density  # the floor, scaled down
    held = unwrap(p, t, res, 2, max_resolution=4096, texels_per_unit=density)
    assert held.resolution > res and held.resolution % 4 == 0
    assert triangle_densities(held, p, t).min() >= 0.99 * density
    assert not overlapping(held.uv, held.resolution, held.resolution).any()
    capped = unwrap(p, t, res, 2, max_resolution=res, texels_per_unit=density)
    assert capped.resolution == res  # no larger map allowed: fitted as without a density
    assert triangle_densities(capped, p, t)[:2].max() < 0.97 * density
    with pytest.raises(ValueError, match="texels per unit"):
        unwrap(p, t, res, 2, texels_per_unit=float("nan"))


# --------------------------------------------------------------------------- layout
def test_unwrap_fits_requested_resolution_without_chart_overlap():
    p, t, _, _ = quad_grid(24, wavy)
    r = unwrap(p, t, 128, 2)
    assert r.uv.shape == (len(t), 3, 2) and r.uv.dtype == np.float32
    assert r.uv.min() >= 0.0 and r.uv.max() <= 1.0
    assert r.chart_count >= 1 and 0.2 < r.utilization <= 1.0
    assert chart_coverages_are_disjoint(r, 128)  # padding keeps charts' texels apart
    assert not overlapping(r.uv, 512, 512).any()


def test_flat_square_keeps_its_proportions():
    p, t, _, _ = quad_grid(4, lambda x, y: 0 * x)
    r = unwrap(p, t, 64, 2)
    extent = r.uv.reshape(-1, 2).max(0) - r.uv.reshape(-1, 2).min(0)
    assert r.chart_count == 1
    assert extent[0] == pytest.approx(extent[1], rel=0.02)  # square stays square
    assert 60 / 64 - 0.05 < extent[0] <= 1.0  # and fills the map up to the padding
    # a 1 x 1 square filling a 64^2 map but for its padding: just under 64 texels per unit
    assert 64 * (60 / 64 - 0.05) < achieved_texel_density(r.uv, 1.0, 64) <= 64.0
    assert achieved_texel_density(r.uv, 4.0, 64) == pytest.approx(achieved_texel_density(r.uv, 1.0, 64) / 2)
    assert achieved_texel_density(r.uv, 0.0, 64) == 0.0


def test_degenerate_triangles_get_finite_uvs_inside_the_map():
    p, t, poly, _ = quad_grid(4, lambda x, y: 0 * x)
    extra = np.array([[0, 0, 1], [0, 1, 2], [5, 5, 5]])  # repeated index, collinear, a point
    r = unwrap(p, np.concatenate([t, extra]), 64, 2, triangle_polygon=np.concatenate([poly, [0, 0, 99]]))
    assert np.isfinite(r.uv).all() and r.uv.min() >= 0 and r.uv.max() <= 1
    assert np.all(r.chart[-3:] == -1) and np.all(r.chart[:-3] >= 0)
    # corners of a degenerate triangle reuse the UVs their vertices have elsewhere
    uv_of_vertex0 = r.uv[:len(t)][t == 0][0]
    assert np.allclose(r.uv[-3, 0], uv_of_vertex0)


def test_non_finite_positions_are_rejected():
    p, t, _, _ = quad_grid(2, lambda x, y: 0 * x)
    p[3, 2] = np.inf
    with pytest.raises(ValueError, match="non-finite"):
        unwrap(p, t, 64, 2)


# --------------------------------------------------------------------------- polygon corners
def test_planar_quads_are_never_split_across_charts():
    p, t, _, loops = quad_grid(20, lambda x, y: 0 * x)
    r = unwrap(p, t, 128, 2)
    _, conflicts = loop_uvs(r.uv, loops, loops.max() + 1)
    assert conflicts == 0


def test_split_non_planar_quads_are_rejoined_one_uv_per_loop():
    p, t, poly, loops = quad_grid(40, wavy)
    plain = unwrap(p, t, 256, 2)
    _, conflicts_plain = loop_uvs(plain.uv, loops, loops.max() + 1)
    assert conflicts_plain > 0  # xatlas does split non-planar quads (62 of 1600 here)

    r = unwrap(p, t, 256, 2, triangle_polygon=poly)
    uv_loop, conflicts = loop_uvs(r.uv, loops, loops.max() + 1)
    assert conflicts == 0 and r.polygons_fixed > 0
    assert np.allclose(uv_loop[loops], r.uv, atol=1e-6)
    assert r.uv.min() >= 0 and r.uv.max() <= 1
    assert chart_coverages_are_disjoint(r, 256)
    assert not overlapping(r.uv, 256, 256, 4).any()


def test_loop_uvs_counts_loops_with_conflicting_uvs():
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0.5, 1]], [[0.2, 0], [0.7, 0.7], [0, 1]]], np.float32)
    loops = np.array([[0, 1, 2], [0, 2, 3], [0, 2, 4]])
    uv_loop, conflicts = loop_uvs(uv, loops, 6)
    assert conflicts == 2  # loop 0 and loop 2 differ in the third triangle
    assert np.allclose(uv_loop[:5], [[0, 0], [1, 0], [1, 1], [0.5, 1], [0, 1]]) and np.all(uv_loop[5] == 0)


# --------------------------------------------------------------------------- cache
def test_cache_hit_returns_identical_uvs(tmp_path):
    p, t, poly, _ = quad_grid(12, wavy)
    cold = unwrap(p, t, 64, 2, tmp_path, poly)
    warm = unwrap(p, t, 64, 2, tmp_path, poly)
    assert not cold.from_cache and warm.from_cache
    assert np.array_equal(cold.uv, warm.uv) and np.array_equal(cold.chart, warm.chart)
    assert warm.chart_count == cold.chart_count
    assert len(list(tmp_path.glob("unwrap-*.npz"))) == 1


def test_cache_key_changes_with_geometry_and_padding(tmp_path):
    p, t, _, _ = quad_grid(6, wavy)
    unwrap(p, t, 64, 2, tmp_path)
    assert not unwrap(p, t, 64, 3, tmp_path).from_cache
    moved = p.copy()
    moved[0, 2] += 1e-3
    assert not unwrap(moved, t, 64, 2, tmp_path).from_cache
    assert len(list(tmp_path.glob("unwrap-*.npz"))) == 3


def test_corrupt_cache_file_is_recomputed(tmp_path):
    p, t, _, _ = quad_grid(6, wavy)
    first = unwrap(p, t, 64, 2, tmp_path)
    (path,) = tmp_path.glob("unwrap-*.npz")
    path.write_bytes(b"not a zip")
    again = unwrap(p, t, 64, 2, tmp_path)
    assert not again.from_cache and np.array_equal(again.uv, first.uv)


def test_repair_finds_a_fold_that_covers_a_texel_centre_and_no_sub_sample():
    """Sponza as one object at 16 texels/m: xatlas folded round columns' cap triangles 0.013 texels over
    their side triangles, a sliver across texel centres (v = 572.5) between the repair's 2x2 test rows
    (572.25, 572.75); the repair saw no overlap and the unwrap's gate refused the layout (9 centres).
    The repair tests the centres too: the later polygon of the two is moved out."""
    from pdic.core.uv_overlap import uv_overlaps
    from pdic.core.xatlas_charts import REPAIR_SAMPLES, _polygons_to_detach

    resolution = 8
    cap = [[3.78, 1.778], [3.10, 2.503], [3.79, 2.507]]  # ends a hundredth of a texel above v = 2.5
    side = [[3.48, 2.494], [3.47, 7.498], [4.03, 2.494]]  # starts a hundredth below it
    uv = np.array([cap, side], np.float64) / resolution
    assert uv_overlaps(uv, None, resolution, resolution) == 1  # the centre (3.5, 2.5) lies in both
    assert uv_overlaps(uv, None, resolution, resolution, REPAIR_SAMPLES) == 0  # no 2x2 point does
    assert _polygons_to_detach(uv.astype(np.float32), np.array([10, 11]), resolution).tolist() == [11]
