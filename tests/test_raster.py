"""Conservative texel rasterisation: closed-form coverage, sample placement, weights."""
from __future__ import annotations

import numpy as np
import pytest

from pdic.core.raster import overlapping, rasterize

HALF = np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]], np.float32)  # lower-left half of the square
SQUARE = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)  # diagonal shared


def sample_positions(s, uv):
    return s.uv_texel(uv)


def test_half_square_triangle_covers_closed_form_texel_count():
    s = rasterize(HALF, 8, 8, samples_per_axis=2)
    x, y = np.meshgrid(np.arange(8), np.arange(8))
    assert np.array_equal(s.coverage, x + y <= 7)  # 36 texels touch the open triangle
    # grid points ((i+.5)/16, (j+.5)/16) with i + j <= 15 (on the diagonal counts): 136 of them
    assert (~s.conservative).sum() == 136
    assert s.conservative.sum() == 0
    assert np.array_equal(s.centre_inside, x + y <= 7)


def test_barycentrics_reproduce_sub_sample_positions():
    s = rasterize(HALF, 8, 8, samples_per_axis=2)
    p = sample_positions(s, HALF)
    grid = (p * 2 - 0.5)  # sub-sample grid coordinates must be integers
    assert np.allclose(grid, np.round(grid), atol=1e-9)
    tx, ty = s.texel % 8, s.texel // 8
    assert np.all((p[:, 0] >= tx) & (p[:, 0] <= tx + 1) & (p[:, 1] >= ty) & (p[:, 1] <= ty + 1))


def test_row_zero_is_the_bottom_of_the_uv_square():
    top = np.array([[[0.0, 0.9], [1.0, 0.9], [0.5, 1.0]]], np.float32)
    s = rasterize(top, 4, 4)
    assert s.coverage[3].any() and not s.coverage[:3].any()
    assert np.all(s.texel // 4 == 3)


def test_shared_edge_sub_samples_are_counted_once():
    # sub-samples at ((i+.5)/16, (i+.5)/16) lie exactly on the shared diagonal
    s = rasterize(SQUARE, 8, 8, samples_per_axis=2)
    assert s.count == 8 * 8 * 4
    assert np.all(np.bincount(s.texel, minlength=64) == 4)
    p = sample_positions(s, SQUARE)
    keys = np.round(p * 2 - 0.5).astype(int)
    assert len(np.unique(keys[:, 1] * 16 + keys[:, 0])) == s.count


def test_thin_sliver_covers_every_texel_it_crosses(rng):
    sliver = np.array([[[0.1, 0.1], [0.9, 0.13], [0.9, 0.1305]]], np.float32)
    s = rasterize(sliver, 32, 32, samples_per_axis=2)
    # reference: texels hit by dense random points of the sliver
    b = rng.dirichlet([1, 1, 1], 200_000)
    pts = b @ sliver[0].astype(np.float64) * 32
    ref = np.zeros((32, 32), bool)
    ref[np.floor(pts[:, 1]).astype(int), np.floor(pts[:, 0]).astype(int)] = True
    assert ref.sum() > 20
    assert np.all(s.coverage[ref])
    assert s.conservative.any()
    assert np.all(s.barycentric >= 0)


def test_no_sample_lies_outside_its_triangle_or_texel(rng):
    uv = rng.random((300, 3, 2)).astype(np.float32) * 0.2 + rng.random((300, 1, 2)).astype(np.float32) * 0.8
    s = rasterize(uv, 37, 29, samples_per_axis=3)
    assert np.all(s.barycentric >= 0) and np.allclose(s.barycentric.sum(1), 1.0)
    p = s.uv_texel(uv)
    tx, ty = s.texel % 37, s.texel // 37
    eps = 1e-6
    assert np.all((p[:, 0] >= tx - eps) & (p[:, 0] <= tx + 1 + eps) & (p[:, 1] >= ty - eps) & (p[:, 1] <= ty + 1 + eps))


def test_texel_weights_sum_to_one(rng):
    uv = rng.random((200, 3, 2)).astype(np.float32)
    s = rasterize(uv, 16, 16, samples_per_axis=2)
    total = np.bincount(s.texel, weights=s.weight, minlength=256).reshape(16, 16)
    assert np.allclose(total[s.coverage], 1.0, atol=1e-6)
    assert np.all(total[~s.coverage] == 0)


def test_each_sub_sample_belongs_to_one_triangle_where_charts_overlap():
    s = rasterize(np.concatenate([SQUARE, SQUARE]), 4, 4, samples_per_axis=2)
    assert s.count == 4 * 4 * 4


def test_centre_mask_is_a_subset_of_coverage(rng):
    uv = rng.random((100, 3, 2)).astype(np.float32)
    s = rasterize(uv, 24, 24)
    assert np.all(s.coverage[s.centre_inside])


def test_degenerate_uv_triangle_gives_no_samples():
    point = np.array([[[0.5, 0.5], [0.5, 0.5], [0.5, 0.5]], [[0.1, 0.1], [0.2, 0.2], [0.3, 0.3]]], np.float32)
    s = rasterize(point, 8, 8)
    assert s.count == 0 and not s.coverage.any()


def test_non_finite_uv_is_rejected():
    bad = HALF.copy()
    bad[0, 1, 0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        rasterize(bad, 8, 8)


def test_overlapping_flags_overlaps_but_not_shared_edges():
    assert not overlapping(SQUARE, 16, 16).any()
    shifted = SQUARE[:1] + np.float32(0.2)  # lower-right half moved along the diagonal
    assert overlapping(np.concatenate([SQUARE, shifted]), 16, 16).tolist() == [True, False, True]


def test_threads_give_the_same_samples_as_one_thread(rng):
    """Batches of triangles spread over threads (an executor's ``map``) are joined in order: the same
    samples, bit for bit, as the serial loop, on a mesh with shared edges and overlapping charts."""
    from pdic.core.executor import Executor

    grid = np.stack(np.meshgrid(np.linspace(0, 1, 41), np.linspace(0, 1, 41)), axis=-1).astype(np.float32)
    a, b, c, d = grid[:-1, :-1], grid[:-1, 1:], grid[1:, 1:], grid[1:, :-1]
    quads = np.concatenate([np.stack([a, b, c], 2).reshape(-1, 3, 2), np.stack([a, c, d], 2).reshape(-1, 3, 2)])
    overlapping_charts = rng.random((500, 3, 2)) * 0.1 + rng.random((500, 1, 2)) * 0.9
    uv = np.concatenate([quads, overlapping_charts.astype(np.float32)])
    serial = rasterize(uv, 300, 200, samples_per_axis=2)
    with Executor(2) as pool:
        threaded = rasterize(uv, 300, 200, samples_per_axis=2, map=pool.map)
    for name in ("texel", "triangle", "barycentric", "weight", "conservative", "coverage", "centre_inside"):
        assert np.array_equal(getattr(serial, name), getattr(threaded, name)), name


@pytest.mark.parametrize("edge_folding", [False, True])
def test_bands_of_rows_give_the_whole_images_samples(rng, edge_folding):
    """Rasterised in bands of 7 rows (core/texels.py rasterises a map's bands on the bake's threads), the
    samples, weights and masks are the whole image's to the bit: on shared edges, overlapping charts,
    slivers and triangles spanning many bands."""
    from pdic.core.raster import RasterMasks, rasterize_rows, row_bands

    grid = np.stack(np.meshgrid(np.linspace(0, 0.6, 23), np.linspace(0, 1, 31)), axis=-1).astype(np.float32)
    a, b, c, d = grid[:-1, :-1], grid[:-1, 1:], grid[1:, 1:], grid[1:, :-1]
    quads = np.concatenate([np.stack([a, b, c], 2).reshape(-1, 3, 2), np.stack([a, c, d], 2).reshape(-1, 3, 2)])
    charts = rng.random((300, 3, 2)) * 0.15 + rng.random((300, 1, 2)) * [0.3, 0.85] + [0.65, 0.0]
    tall = np.array([[[0.62, 0.01], [0.64, 0.01], [0.63, 0.99]], [[0.9, 0.02], [0.99, 0.5], [0.91, 0.97]]])
    uv = np.concatenate([quads, charts, tall]).astype(np.float32)
    whole = rasterize(uv, 120, 90, 2, edge_folding=edge_folding, footprint_side=0.8)
    masks = RasterMasks.empty(120, 90)
    bands = [rasterize_rows(uv, 120, 90, 2, rows, masks, edge_folding=edge_folding, footprint_side=0.8)
             for rows in row_bands(90, 7)]
    assert len(bands) == 13 and bands[0].rows == (0, 7) and whole.rows is None
    for name in ("texel", "triangle", "barycentric", "weight", "conservative"):
        assert np.array_equal(getattr(whole, name), np.concatenate([getattr(s, name) for s in bands])), name
    for name in ("coverage", "centre_inside", "centre_triangle"):
        assert np.array_equal(getattr(whole, name), getattr(masks, name).reshape(90, 120)), name
    assert whole.past_edges == sum(s.past_edges for s in bands) and (whole.past_edges > 0) == edge_folding


def test_one_pair_per_sample_matches_the_sort_of_all_pairs(rng):
    """Shared grid points keep the pair most inside its triangle, then the lowest triangle, in sample order."""
    from pdic.core.raster import _one_per_sample

    sample = rng.integers(0, 500, 3000)
    tri = rng.integers(0, 40, 3000)
    least = rng.integers(0, 4, 3000) / 4.0  # many ties in ``least``
    order = np.lexsort((tri, -least, sample))
    expected = order[np.r_[True, sample[order][1:] != sample[order][:-1]]]
    assert np.array_equal(_one_per_sample(sample, tri, least, 500), expected)  # dense tables
    assert np.array_equal(_one_per_sample(sample, tri, least, 10 ** 6), expected)  # a sparse grid: one sort


@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_a_centre_on_a_shared_edge_belongs_to_the_triangle_under_blenders_scan_point(order):
    """A 2x2-texel square split along its diagonal through texel (0, 0)'s and (1, 1)'s centres: Blender's bake
    gives those texels to the triangle under (x + 0.501, y + 0.502), above the diagonal, whatever the
    triangles' order; the other texels keep the triangle under their centre."""
    above = [(0, 0), (2, 2), (0, 2)]
    below = [(0, 0), (2, 0), (2, 2)]
    tris = [above, below]
    uv = np.array([tris[i] for i in order], np.float64) / 2
    s = rasterize(uv, 2, 2, 2)
    up, down = order.index(0), order.index(1)
    assert s.centre_triangle[0, 0] == up and s.centre_triangle[1, 1] == up
    assert s.centre_triangle[1, 0] == up and s.centre_triangle[0, 1] == down  # row 1 is v in [0.5, 1)
