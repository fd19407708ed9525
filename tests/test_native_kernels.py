"""The compiled kernels of Equation 3 (core/native/pdic_native.c) give the numpy code's results to the bit.

The library is built by tools/setup.sh with this machine's C compiler; these tests run the real one.
Each kernel is compared with the numpy function it replaces on inputs made to expose a different
order of operations (magnitudes over many decades, NaN and far-away points), and a whole Final bake
with the library against one with the numpy kernels.
"""
import copy
from dataclasses import replace

import numpy as np
import pytest

from pdic.core import native_kernels, real_rays
from pdic.core.albedo import albedo_numpy, bilinear_numpy
from pdic.core.gather_cells import CellSums
from pdic.core.hemisphere import Hemisphere
from pdic.core.interpolation import equation3_sums, ward_pairs
from pdic.core.pipeline import bake
from pdic.core.rays import Hits
from pdic.core.settings import preset
from pdic.core.vectors import dots
from pdic.core.zone_grid import ZoneGrid, morton_keys_numpy, spatial_order

from scenes import box_faces, box_on_ground, lamp_box, quad_scene

LIB = native_kernels.library()


def test_the_library_is_built_and_passes_its_check():
    assert LIB is not None, f"Equation 3 runs in numpy here: {native_kernels.status()} (tools/build_native.py)"
    assert native_kernels.status().startswith("compiled (pdic_native-")


def _unit(v):
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _records(rng, K):
    p_k = rng.uniform(-10, 10, (K, 3)) * 10.0 ** rng.uniform(-3, 1, (K, 1))
    return p_k, _unit(rng.normal(size=(K, 3))), 10.0 ** rng.uniform(-2.5, 0.5, K)


def _points(rng, m, p_k):
    q = p_k[rng.integers(0, len(p_k), m)] + rng.normal(scale=0.3, size=(m, 3))
    q[::97] = np.nan
    q[1::97] = [1e300, 0.0, 0.0]
    q[2::97] = np.inf
    return q, _unit(rng.normal(size=(m, 3)))


@pytest.mark.parametrize("cell_per_zone", [1.0, 3.0])
@pytest.mark.parametrize("sparse", [False, True])
def test_zone_pairs_equal_numpy(cell_per_zone, sparse):
    rng = np.random.default_rng(11)
    p_k, _, R = _records(rng, 3000)
    q, _ = _points(rng, 20000, p_k)
    grid = ZoneGrid(p_k, R, cell_per_zone)
    if sparse and grid.cells is None:  # the sorted table ZoneGrid uses for sparse cells, over the same cells
        grid = copy.copy(grid)
        key = np.flatnonzero(np.diff(grid.first))
        grid.cells, grid.start, grid.stop = key, grid.first[key], grid.first[key + 1]
    rows, rec = native_kernels.zone_pairs(LIB, grid, q)
    want_rows, want_rec = grid.pairs_numpy(q)
    assert len(rows) > 20000
    assert np.array_equal(rows, want_rows) and np.array_equal(rec, want_rec)


def test_ward_weights_and_acceptance_equal_numpy():
    rng = np.random.default_rng(12)
    p_k, n_k, R = _records(rng, 2000)
    q, n = _points(rng, 10000, p_k)
    n[5::101] = np.nan  # a broken normal: NaN weight, never accepted, in both
    rows, rec = ZoneGrid(p_k, R * 1.5).pairs_numpy(q)
    for R_add in (0.0, 0.013):
        got = native_kernels.ward_accept(LIB, q, n, p_k, n_k, R, R_add, 1.5, rows, rec)
        want = ward_pairs(q, n, p_k, n_k, R, R_add, 1.5, rows, rec)
        assert 0 < got[1].sum() < len(rows)
        for x, y in zip(got, want):
            assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True)


@pytest.mark.parametrize("channels", [3, 6])
def test_equation3_sums_equal_numpy(channels):
    rng = np.random.default_rng(13)
    K, m = 1500, 8000
    p_k, n_k, R = _records(rng, K)
    q, n = _points(rng, m, p_k)
    rows, rec = ZoneGrid(p_k, R).pairs_numpy(q)
    w = 10.0 ** rng.uniform(-3, 6, len(rows))
    E_k = rng.uniform(0, 5, (K, channels)) * 10.0 ** rng.uniform(-4, 4, (K, 1))
    g_r, g_t = (rng.normal(size=(K, channels, 3)) * 10.0 ** rng.uniform(-3, 3, (K, 1, 1)) for _ in range(2))
    at = np.take(q, rows, axis=0) + rng.normal(scale=1e-3, size=(len(rows), 3))
    for args in ((None, g_r, g_t, R), (at, g_r, g_t, None), (None, None, None, R), (None, g_r, None, None)):
        got = native_kernels.equation3_sums(LIB, m, q, n, args[0], p_k, n_k, E_k, *args[1:], rows, rec, w)
        want = equation3_sums(m, q, n, args[0], p_k, n_k, E_k, *args[1:], rows, rec, w)
        assert (got[0] == 0).any() and (got[0] > 0).any()  # some estimates clamped at zero, some not
        for x, y in zip(got, want):
            assert (x is None and y is None) or np.array_equal(x, y)


def test_bilinear_texture_samples_equal_numpy():
    rng = np.random.default_rng(16)
    for H, W in ((1, 1), (3, 5), (64, 48)):
        pixels = rng.random((H, W, 3), dtype=np.float32) * 10.0 ** rng.uniform(-3, 3, (H, W, 1)).astype(np.float32)
        uv = rng.uniform(-50, 50, (20000, 2))
        uv[::3] = rng.uniform(0, 1, (len(uv[::3]), 2))
        assert np.array_equal(native_kernels.bilinear_rgb(LIB, pixels, uv), bilinear_numpy(pixels, uv))
    # A UV too large for an integer texel index reads some texel of the image, not memory past it.
    far = native_kernels.bilinear_rgb(LIB, pixels, np.array([[1e300, -1e300], [-4e18, 9e18]]))
    assert np.isfinite(far).all() and (far >= pixels.min()).all() and (far <= pixels.max() * (1 + 1e-6)).all()


def test_albedos_equal_numpy():
    rng = np.random.default_rng(17)
    scene = native_kernels._textured_scene(rng, 500)
    triangles = rng.integers(0, 500, 30000)
    bary = rng.uniform(-0.5, 1.5, (30000, 2)) * 10.0 ** rng.uniform(-1, 3, (30000, 1))
    bary[::101] = np.nan  # a NaN UV reads the texture at 0, in both
    got = native_kernels.albedo(LIB, scene, triangles, bary)
    want = albedo_numpy(scene, triangles, bary)
    textured = scene.materials.texture[scene.geometry.material[triangles]] >= 0
    assert 0.1 < textured.mean() < 0.9 and (got[textured] == 1.0).any()  # textures brighter than 1 clipped
    assert got.dtype == want.dtype == np.float32 and np.array_equal(got, want)


def _frames(rng, B):
    n = _unit(rng.normal(size=(B, 3)))
    t1 = _unit(np.cross(n, rng.normal(size=(B, 3))))
    p_k = rng.uniform(-10, 10, (B, 3)) * 10.0 ** rng.uniform(-3, 3, (B, 1))
    return p_k, t1, np.cross(n, t1), n


@pytest.mark.parametrize("rows, columns", [(16, 32), (1, 1), (5, 3)])
def test_gathering_rays_equal_numpy(rows, columns):
    rng = np.random.default_rng(18)
    H, B = Hemisphere(rows, columns), 300
    cells = rng.choice(B * H.cells, min(B * H.cells, 40000), replace=False)
    u = rng.random((len(cells), 2))
    u[::50] = [1.0 - 2 ** -53, 0.0]  # the horizon: sin^2 theta a rounding below 1, rays nearly tangent
    u[1::50] = 0.0
    frames = _frames(rng, B)
    want = real_rays.gathering_rays_numpy(H, cells, u, frames, 3e-5)
    got = native_kernels.gathering_rays(LIB, H, cells, u, frames, 3e-5)
    for name, x, y in zip(("w_local", "d_world", "origin"), want, got):
        assert np.array_equal(x, y), name
    if rows > 1:  # the horizon was drawn: rays nearly tangent to their record's surface
        assert (want[0][:, 2] < 1e-7).any() and (want[0][:, 2] > 0.9).any()


def test_cosine_directions_equal_numpy():
    from pdic.core.sampling import cosine_directions_numpy

    rng = np.random.default_rng(19)
    m = 50000
    n = _unit(rng.normal(size=(m, 3)))
    n[::7, 2] = rng.choice([0.0, -0.0, 1e-300, -1e-300], size=len(n[::7]))  # on the tangents' seam, z's sign
    n[::7] = _unit(n[::7])
    n[1::97] = [0.0, 0.0, -1.0]
    n[2::97] = np.nan
    u = rng.random((m, 2))
    u[::53] = [0.5, 0.5]  # the disk's centre: phi 0
    u[1::53] = [1.0 - 2 ** -53, 0.5]  # the disk's edge, a direction a rounding above the horizon
    u[2::53] = [0.25, 0.25]  # its diagonal, |a| = |b|
    want = cosine_directions_numpy(u, n)
    got = native_kernels.cosine_directions(LIB, u, n)
    assert np.array_equal(want.view(np.uint64), got.view(np.uint64))  # NaN payloads and zeros' signs too
    finite = np.isfinite(want).all(axis=1)
    assert finite.sum() > 0.98 * m and np.allclose(np.linalg.norm(want[finite], axis=1), 1.0)
    assert (dots(want[finite], n[finite]) >= 0.0).all()


def test_pattern_directions_equal_numpy():
    """The crevice test's fixed pattern turned into each sample's frame, normals of every sign, NaN kept."""
    from pdic.core.crevice_records import _pattern
    from pdic.core.sampling import pattern_directions_numpy

    rng = np.random.default_rng(21)
    n = _unit(rng.normal(size=(20000, 3)))
    n[::7, 2] = rng.choice([0.0, -0.0, 1e-300, -1e-300], size=len(n[::7]))
    n[::7] = _unit(n[::7])
    n[1::97] = [0.0, 0.0, -1.0]
    n[2::97] = np.nan
    for pattern in (_pattern(), rng.normal(size=(3, 3))):
        want = pattern_directions_numpy(pattern, n)
        got = native_kernels.pattern_directions(LIB, pattern, n)
        assert want.shape == got.shape == (len(n), len(pattern), 3)
        assert np.array_equal(want.view(np.uint64), got.view(np.uint64))
    finite = np.isfinite(want).all(axis=(1, 2))
    assert np.allclose(np.linalg.norm(want[finite], axis=2), np.linalg.norm(pattern, axis=1))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_algorithm_1_sums_equal_numpy(dtype):
    """Algorithm 1's last line over a block's pairs: pass 2 sums into the photons' float32 fields, the hole
    records into float64 ones; candidates met by one pair, by hundreds, and none."""
    from pdic.core.irradiance_cache import _accumulate, _accumulate_numpy

    rng = np.random.default_rng(20)
    N, m = 5000, 40000
    members = np.concatenate([rng.integers(0, 50, m // 2), rng.integers(0, N - 100, m // 2)])  # crowded and sparse
    w = rng.random(m) * 10.0 ** rng.uniform(-12, 3, m)
    E_k = rng.normal(size=(m, 3)) * 10.0 ** rng.uniform(-6, 4, (m, 1))
    start = (rng.random(N) * 3).astype(dtype), (rng.random((N, 3)) * 3).astype(dtype)
    want = tuple(a.copy() for a in start)
    got = tuple(a.copy() for a in start)
    _accumulate_numpy(*want, members, w, E_k)
    slot_of = np.full(N, -1, np.int64)
    for part in np.array_split(np.arange(m), 7):  # blocks one after another, as place_records calls it
        assert native_kernels.accumulate(LIB, *got, members[part], w[part], E_k[part], slot_of)
    dispatched = tuple(a.copy() for a in start)
    for part in np.array_split(np.arange(m), 7):
        _accumulate(*dispatched, members[part], w[part], E_k[part], slot_of)
    blocks = tuple(a.copy() for a in start)
    for part in np.array_split(np.arange(m), 7):
        _accumulate_numpy(*blocks, members[part], w[part], E_k[part])
    for a, b, c in zip(blocks, got, dispatched):
        assert a.dtype == b.dtype == c.dtype == dtype and np.array_equal(a, b) and np.array_equal(a, c)
    assert (slot_of == -1).all()  # the scratch is left as found
    assert not np.array_equal(want[0], start[0]) and np.array_equal(want[0][N - 100:], start[0][N - 100:])
    with pytest.raises(ValueError, match="outside"):
        native_kernels.accumulate(LIB, *got, np.array([N]), w[:1], E_k[:1], slot_of)
    other = np.float64 if dtype == np.float32 else np.float32
    assert not native_kernels.accumulate(LIB, got[0].astype(other), got[1], members, w, E_k, slot_of)
    assert not native_kernels.accumulate(LIB, got[0], got[1][:, :2], members, w, E_k, slot_of)  # the caller's numpy
    frozen = got[0].copy()
    frozen.flags.writeable = False  # numpy refuses to add into it, and so is left to say so
    assert not native_kernels.accumulate(LIB, frozen, got[1], members, w, E_k, slot_of)


def test_gathering_tallies_equal_numpy():
    rng = np.random.default_rng(19)
    H, B = Hemisphere(8, 16), 200
    cells = rng.choice(B * H.cells, 20000, replace=False)
    w, d, o = real_rays.gathering_rays_numpy(H, cells, rng.random((len(cells), 2)), _frames(rng, B), 1e-4)
    t = np.where(rng.random(len(cells)) < 0.2, np.inf, 10.0 ** rng.uniform(-310, 3, len(cells)))
    t[::97] = 0.0  # a hit on the origin: 1 / t capped, not inf
    hits = Hits(t, np.where(np.isinf(t), -1, rng.integers(0, 1000, len(t))), rng.random((len(t), 2)))
    sums = [CellSums(B, H), CellSums(B, H)]
    # cells virtual rays reached before
    earlier = (rng.choice(B * H.cells, 5000, replace=False), rng.random((5000, 3)), _unit(rng.random((5000, 3))),
               rng.uniform(0, 5, 5000))
    for s in sums:
        s.add_rays(*earlier)
    want = real_rays.tally_real_rays_numpy(sums[0], cells, w, hits, o, d)
    got = native_kernels.tally_real_rays(LIB, sums[1], cells, w, hits, o, d)
    for name, x, y in zip(("hit", "q", "inv_sum", "inv_n"), want, got):
        assert np.array_equal(x, y), name
    assert np.isfinite(want[2]).all() and want[3].sum() == (t < np.inf).sum()
    for name in ("rot_sum", "count", "r_min", "L_sum"):
        assert np.array_equal(getattr(sums[0], name), getattr(sums[1], name)), name


@pytest.mark.parametrize("rows, columns, sky", [(16, 32, False), (8, 16, True), (1, 6, False), (5, 1, False),
                                               (1, 1, True)])
def test_cell_gradients_equal_numpy(rows, columns, sky):
    rng = np.random.default_rng(23)
    sums = native_kernels._cell_sums(CellSums(40, Hemisphere(rows, columns), sky), rng)
    sums.r_min[::7] = 0.0  # a hit on the record: the floor keeps the gradient finite
    sums.L_sum[-sums.H.cells:] = -0.0  # a record whose every sum is of -0.0 terms: +0.0, as numpy's
    want = sums.local_gradients(1e-4)
    got = native_kernels.cell_gradients(LIB, sums, 1e-4)
    for name, x, y in zip(("E", "grad_r", "grad_t"), want, got):
        assert native_kernels._same_bits(x, y), name
    assert not np.signbit(want[0][-1]).any()
    assert np.isfinite(want[2]).all() and (np.abs(want[2]) > 0).any() == (rows > 1 or columns > 1)


@pytest.mark.parametrize("width", [3, 6])
def test_cell_radiance_sums_equal_numpy(width):
    rng = np.random.default_rng(29)
    table = rng.normal(size=(5000, width))
    rows = rng.integers(0, 5000, 20000)  # many rows twice: numpy keeps each row's last sum, not their total
    values = rng.normal(size=(20000, 3))
    want = table.copy()
    want[rows, :3] += values
    native_kernels.add_rows3(LIB, table, rows, values)
    assert np.array_equal(table, want)
    with pytest.raises(IndexError, match="rows outside"):
        native_kernels.add_rows3(LIB, table, np.array([5000]), values[:1])
    with pytest.raises(ValueError, match="add_rows3"):
        native_kernels.add_rows3(LIB, table[:, :2].copy(), rows, values)
    table.flags.writeable = False  # not written behind numpy's back
    with pytest.raises(ValueError, match="add_rows3"):
        native_kernels.add_rows3(LIB, table, rows, values)


def test_cell_gradients_refuse_sums_the_kernel_would_read_past():
    sums = CellSums(2, Hemisphere(2, 2))
    sums.L_sum = np.zeros((sums.size, 9))  # more channels than the kernel holds
    with pytest.raises(ValueError, match="cell sums"):
        native_kernels.cell_gradients(LIB, sums, 1e-3)
    sums = CellSums(2, Hemisphere(2, 2))
    sums.r_min = sums.r_min[:-1]  # shorter than the records' cells
    with pytest.raises(ValueError, match="cell sums"):
        native_kernels.cell_gradients(LIB, sums, 1e-3)


@pytest.mark.parametrize("albedo, open_cells, corner, gap", [(True, True, True, True), (False, False, True, True),
                                                             (True, True, False, True), (True, False, True, False)])
def test_hit_cells_equal_numpy(albedo, open_cells, corner, gap):
    rng = np.random.default_rng(20)
    caster, sources, hits = native_kernels._grid_hits(rng, 2000, 50000, albedo, open_cells)
    sources.deviations = replace(sources.deviations, corner_gathering=corner, gap_gathering=gap)
    hits[4][::5] *= 1e-3  # hits close to their record: in the gap's reach
    want = real_rays.hit_cells_numpy(caster, sources, *hits)
    got = native_kernels.hit_cells(LIB, caster, sources.hit_grid, *hits[:-1], real_rays.gap_tests(sources, hits[-1]))
    for name, x, y in zip(("n_hit", "E", "centroid", "rho", "is_open", "near", "gap"), want, got):
        assert (x is None and y is None) or (x.dtype == y.dtype and np.array_equal(x, y)), name
    n_hit, E, centroid, rho, is_open, near, in_gap = want
    assert (rho is None) == (not albedo) and is_open.any() == open_cells
    assert 0 < near.mean() < 1 and (0 < in_gap.mean() < 1) == gap
    # each hit reads a cell of its own triangle, on the side it met
    grid, triangle = sources.hit_grid, hits[0]
    back = dots(caster.face_normals[triangle], hits[3]) > 0
    assert np.array_equal(n_hit, np.where(back[:, None], -1, 1) * caster.face_normals[triangle])
    cell_of = {tuple(c): k for k, c in enumerate(grid.centroid.tolist())}
    cell = np.array([cell_of[tuple(c)] for c in centroid.tolist()])
    assert ((cell >= grid.offset[triangle]) & (cell < grid.offset[triangle] + grid.side[triangle] ** 2)).all()
    assert np.array_equal(E, grid.E[back.astype(int), cell].astype(np.float64))


def test_hit_cells_refuse_a_cell_table_the_kernel_would_misread():
    rng = np.random.default_rng(21)
    caster, sources, hits = native_kernels._grid_hits(rng, 50, 100)
    grid = sources.hit_grid
    V = len(grid.cells)
    twice = np.concatenate([grid.cells, grid.cells])
    unaligned = np.zeros(V * 64 + 1, np.uint8)[1:].view(grid.cells.dtype)
    for bad, why in ((np.zeros(V, [("centroid", "<f8", (3,))]), "dtype"), (grid.cells[:-1], f"{V - 1} rows"),
                     (twice[::2], "not contiguous"), (unaligned, "8-byte boundary")):
        object.__setattr__(grid, "cells", bad)
        with pytest.raises(ValueError, match=f"hit grid cells.*{why}"):
            native_kernels.hit_cells(LIB, caster, grid, *hits[:-1], real_rays.gap_tests(sources, hits[-1]))


@pytest.mark.filterwarnings("error")  # numpy's keys of NaN or infinite points warn no one
@pytest.mark.parametrize("case", ["scattered", "flat", "nan", "inf", "inf_column", "one", "repeated"])
def test_morton_keys_and_order_equal_numpy(case):
    rng = np.random.default_rng(21)
    p = rng.normal(size=(30000, 3)) * [1.0, 1e-4, 300.0]
    if case == "flat":
        p[:, 2] = 7.0  # an axis of zero extent
    elif case == "nan":
        p[11, 1] = np.nan  # numpy's box turns NaN: every key 0
    elif case == "inf":
        p[5, 0] = -np.inf  # the extent infinite: the scale 0
    elif case == "inf_column":
        p[:, 0] = np.inf  # inf - inf: the extent NaN
    elif case == "one":
        p = p[:1]
    elif case == "repeated":
        p = p[rng.integers(0, 40, len(p))]  # few distinct keys: the stable order keeps each run's order
    keys = morton_keys_numpy(p)
    assert np.array_equal(native_kernels.morton_keys(LIB, p), keys)
    order = native_kernels.morton_order(LIB, p)
    assert np.array_equal(order, np.argsort(keys, kind="stable"))
    assert np.array_equal(spatial_order(p), order)
    # a NaN or infinite coordinate makes the box's extent NaN or infinite, and a lone point has none: every key 0
    assert (case in ("nan", "inf", "inf_column", "one")) == (not keys.any())
    with pytest.raises(ValueError, match=r"\(m, 3\)"):  # the C reads three coordinates a point
        native_kernels.morton_order(LIB, p[:, :2])


def test_record_walls_equal_numpy():
    from pdic.core.record_walls import beyond_wall_and_reach

    rng = np.random.default_rng(31)
    rows, records, p, p_k, n_k, wall, reach = native_kernels._wall_pairs(rng, 3000, 500, 100_000)
    p[0], rows[:40], records[:40] = p_k[7], 0, 7  # a point on its record: atan2(0, 0)
    want = beyond_wall_and_reach(wall[records], p[rows] - p_k[records], n_k[records], reach[records])
    got = native_kernels.pair_walls(LIB, rows, records, p, p_k, n_k, wall, reach)
    assert all(np.array_equal(a, b) for a, b in zip(want, got))
    past_reach, past_far = want
    assert past_reach.mean() > 0.1 and (past_reach & ~past_far).mean() > 0.01 and past_far.mean() > 0.01
    assert not past_reach[records == 2].any()  # a record with no wall in any sector
    with pytest.raises(ValueError, match="pair up"):
        native_kernels.pair_walls(LIB, rows, records[:-1], p, p_k, n_k, wall, reach)
    with pytest.raises(ValueError, match="past the points"):  # the C would read another record's memory
        native_kernels.pair_walls(LIB, rows, np.full_like(records, len(p_k)), p, p_k, n_k, wall, reach)
    with pytest.raises(ValueError, match="WALL_RAYS"):
        native_kernels.pair_walls(LIB, rows, records, p, p_k, n_k, wall[:, :5], reach)
    with pytest.raises(ValueError, match="float32"):
        native_kernels.pair_walls(LIB, rows, records, p, p_k, n_k, wall.astype(np.float64), reach)


def _area_inputs(rng, k: int = 400, m: int = 16):
    """Receivers spread over decades around an area light 1.5 m up facing down (some behind it, one at its
    centre, one not a number), their normals random, samples over its square."""
    pk = rng.normal(size=(k, 3)) * np.exp(rng.uniform(-6, 4, size=(k, 1)))
    nsk, ngk = (v / np.linalg.norm(v, axis=1, keepdims=True) for v in rng.normal(size=(2, k, 3)))
    c, N = np.array([0.2, 0.1, 1.5]), np.array([0.0, 0.0, -1.0])
    pk[0], pk[1] = c, np.nan
    xy = rng.uniform(-0.25, 0.25, size=(k, m, 2))
    xy[0, 0] = 0.0  # a sample on the receiver itself: d = 0
    corners = c + np.array([[a, b, 0.0] for a in (-0.25, 0.25) for b in (-0.25, 0.25)])
    return pk, nsk, ngk, xy, c, N, corners


def test_area_light_samples_and_facing_points_equal_numpy():
    from pdic.core.lights import area_facing_numpy, area_samples_numpy

    pk, nsk, ngk, xy, c, N, corners = _area_inputs(np.random.default_rng(7))
    U, V = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    want = area_samples_numpy(xy, pk, nsk, ngk, c, N, U, V, 16.0, 2e-4)
    got = native_kernels.area_samples(LIB, xy, pk, nsk, ngk, c, N, U, V, 16.0, 2e-4)
    for a, b in zip(want, got):
        assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
    assert 0 < want[2].sum() < want[2].size  # some samples light their point, some do not
    facing = area_facing_numpy(pk, nsk, ngk, c, N, corners)
    assert np.array_equal(facing, native_kernels.area_facing(LIB, pk, nsk, ngk, c, N, corners))
    assert 0 < facing.sum() < len(facing)
    with pytest.raises(ValueError, match="disagree"):
        native_kernels.area_samples(LIB, xy[:-1], pk, nsk, ngk, c, N, U, V, 16.0, 2e-4)


@pytest.mark.parametrize("edges", [False, True])
def test_a_point_lights_sums_equal_numpy(edges):
    """A point light's light at the points its rays left from (rows distinct, in order), weights over decades,
    blocked rays, into E and the edge evidence."""
    from pdic.core.direct import DirectResult, _add_hard_light_numpy

    rng = np.random.default_rng(22)
    n, k = 30000, 20000
    rows = np.sort(rng.choice(n, k, replace=False))
    P = np.array([3000.0, 1e-3, 0.0])
    weight = 10.0 ** rng.uniform(-9, 1, k)
    vis = np.where(rng.random(k) < 0.3, 0.0, rng.random(k))
    sums = [rng.random((n, 3)) * 10.0 ** rng.uniform(-6, 3, (n, 1)) for _ in range(3)]
    if not edges:
        sums[1:] = [None, None]
    E_before = sums[0].copy()
    want = DirectResult(*sums)
    got = DirectResult(*(None if a is None else a.copy() for a in sums))
    _add_hard_light_numpy(want, rows, P, weight, vis)
    native_kernels.add_hard_light(LIB, got.E, got.edge_lit, got.edge_open, rows, P, weight, vis)
    for a, b in zip((want.E, want.edge_lit, want.edge_open), (got.E, got.edge_lit, got.edge_open)):
        assert (a is None) == (b is None) and (a is None or np.array_equal(a, b))
    assert (want.edge_lit is not None) == edges
    untouched = np.setdiff1d(np.arange(n), rows)
    assert not np.array_equal(want.E, E_before) and np.array_equal(got.E[untouched], E_before[untouched])
    with pytest.raises(ValueError, match="outside"):
        native_kernels.add_hard_light(LIB, got.E, None, None, np.array([n]), P, weight[:1], vis[:1])
    with pytest.raises(ValueError, match="C-contiguous"):
        native_kernels.add_hard_light(LIB, got.E.astype(np.float32), None, None, rows, P, weight, vis)
    frozen = got.E.copy()
    frozen.flags.writeable = False  # numpy would refuse to add into it; the kernel must not write it either
    with pytest.raises(ValueError, match="writable"):
        native_kernels.add_hard_light(LIB, frozen, None, None, rows, P, weight, vis)


def test_soft_falloff_lamp_samples_equal_numpy():
    from pdic.core.lights import disk_samples_numpy

    pk, nsk, ngk, xy, c, N, _ = _area_inputs(np.random.default_rng(9))
    n_disk = np.cross(nsk, ngk)
    q = pk[:, None, :] + np.concatenate([xy, xy[..., :1]], axis=2) * 4.0  # samples around each point, some on it
    q[0, 0] = pk[0]
    want = disk_samples_numpy(q, pk, nsk, ngk, n_disk)
    got = native_kernels.disk_samples(LIB, q, pk, nsk, ngk, n_disk)
    for a, b in zip(want, got):
        assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
    assert 0 < want[1].sum() < want[1].size


def test_shadow_segments_equal_numpy():
    from pdic.core.rays import shadow_segments_numpy

    rng = np.random.default_rng(11)
    points = rng.normal(size=(3000, 3)) * np.exp(rng.uniform(-8, 6, size=(3000, 1)))
    normals = rng.normal(size=(3000, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    targets = rng.normal(size=(3000, 3)) * 3.0
    targets[::50] = points[::50]  # zero-length segments
    normals[1::50] = np.cross(normals[1::50], targets[1::50] - points[1::50])  # normals square to the segment
    points[2::97] = np.nan
    want = shadow_segments_numpy(points, normals, targets, 1e-3)
    got = native_kernels.shadow_segments(LIB, points, normals, targets, 1e-3)
    for a, b in zip(want, got):
        assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
        if a.dtype.kind == "f":  # the sign of a zero too
            assert np.array_equal(np.signbit(a), np.signbit(b))
    assert 0 < want[3].sum() < len(points)


@pytest.mark.parametrize("kind", ["area", "soft point"])
def test_a_soft_lit_bake_with_the_library_equals_one_without_to_the_bit(monkeypatch, kind):
    from pdic.core import scene as sc

    lamp = (sc.AreaLight("panel", np.array([0.5, 0.5, 0.95]), np.array([0, 0, -1.0]), np.array([1.0, 0, 0]),
                         np.array([0, 1.0, 0]), 0.3, 0.2, "RECTANGLE", np.full(3, 40.0)) if kind == "area"
            else sc.PointLight("bulb", np.array([0.5, 0.5, 0.8]), np.full(3, 100.0), 0.1))

    def scene():
        return quad_scene(box_faces(), {"floor": (0, 16), "back": (1, 16)}, [lamp])

    settings = preset("FINAL", photons=6000, max_bounces=4, threads=2, hemisphere_theta=6, hemisphere_phi=12)
    compiled = bake(scene(), settings)
    monkeypatch.setattr(native_kernels, "library", lambda: None)
    numpy_only = bake(scene(), settings)
    assert compiled.stats["kernels"].startswith("compiled")
    assert compiled.stats["counters"]["shadow_rays_area" if kind == "area" else "shadow_rays_point"] > 1000
    for target, E in compiled.lightmaps.items():
        assert E[..., :3].max() > 0
        assert np.array_equal(E, numpy_only.lightmaps[target]), target


def test_dots_sum_left_to_right():
    a, b = np.array([[1e16, 1.0, -1e16]]), np.ones((1, 3))
    assert dots(a, b)[0] == 0.0  # (1e16 + 1) - 1e16: the 1 is lost; einsum's (a0 + a2) + a1 would keep it


@pytest.mark.parametrize("scene, quality", [(lambda: lamp_box(24), "FINAL"), (lambda: box_on_ground(12), "FINAL"),
                                            (lambda: lamp_box(24), "PREVIEW")])
def test_a_bake_with_the_library_equals_one_without_to_the_bit(monkeypatch, scene, quality):
    settings = preset(quality, photons=6000, max_bounces=4, threads=2, hemisphere_theta=6, hemisphere_phi=12)
    compiled = bake(scene(), settings)
    monkeypatch.setattr(native_kernels, "library", lambda: None)
    numpy_only = bake(scene(), settings)
    assert compiled.stats["kernels"].startswith("compiled")
    assert sum(float(E.sum()) for E in compiled.indirect.values()) > 0
    for target, E in compiled.lightmaps.items():
        assert np.array_equal(E, numpy_only.lightmaps[target]), target
        assert np.array_equal(compiled.indirect[target], numpy_only.indirect[target]), target


def _load_again(monkeypatch):
    """Forget the loaded library (for this test only): the next library() loads and checks it again."""
    monkeypatch.setattr(native_kernels, "_status", None)
    monkeypatch.setattr(native_kernels, "_lib", None)


def test_a_missing_library_leaves_numpy_and_says_why(monkeypatch, tmp_path):
    monkeypatch.setattr(native_kernels, "NATIVE_DIR", tmp_path)
    _load_again(monkeypatch)
    assert native_kernels.library() is None
    assert native_kernels.status().startswith("numpy (no compiled kernels for linux-x64")
    # and the lookup still works
    rng = np.random.default_rng(3)
    p_k, _, R = _records(rng, 50)
    assert len(ZoneGrid(p_k, R).pairs(p_k)[0]) >= 50


def test_a_library_that_gives_other_numbers_is_refused(monkeypatch):
    """A build that rounds otherwise (fused multiply-adds, say) fails the check at load: numpy runs."""
    exact = native_kernels.ward_accept

    def rounded_otherwise(*args):
        w, ok, d2 = exact(*args)
        return np.nextafter(w, np.inf), ok, d2

    monkeypatch.setattr(native_kernels, "ward_accept", rounded_otherwise)
    _load_again(monkeypatch)
    assert native_kernels.library() is None
    assert "failed its check: Ward weights differ" in native_kernels.status()


def test_a_library_whose_check_raises_is_not_used(monkeypatch):
    """A library this code cannot call (a missing symbol, a wrong signature) leaves numpy, not a failed bake."""
    def raising(lib):
        raise AttributeError("undefined symbol: pdic_new_kernel")

    monkeypatch.setattr(native_kernels, "_self_check", raising)
    _load_again(monkeypatch)
    assert native_kernels.library() is None
    assert "failed its check: AttributeError: undefined symbol" in native_kernels.status()


def test_the_numpy_code_the_check_runs_does_not_wait_for_the_library(monkeypatch):
    """The check compares with numpy functions that ask for the library themselves: they get None."""
    seen = []
    monkeypatch.setattr(native_kernels, "_self_check", lambda lib: seen.append(native_kernels.library()))
    _load_again(monkeypatch)
    assert native_kernels.library() is not None and seen == [None]


def test_platform_names_follow_blender():
    assert native_kernels.platform_name("Linux", "x86_64") == "linux-x64"
    assert native_kernels.platform_name("Windows", "AMD64") == "windows-x64"
    assert native_kernels.platform_name("Darwin", "arm64") == "macos-arm64"
    assert native_kernels.library_path("windows-x64").name == "pdic_native-windows-x64.dll"
    assert native_kernels.library_path("macos-arm64").name == "pdic_native-macos-arm64.dylib"
