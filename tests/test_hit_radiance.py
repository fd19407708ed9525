"""The hit grid (deviation: hit-grid): every gathering hit reads the irradiance of its triangle's cell."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from pdic.core.executor import make_executor
from pdic.core import scene as sc
from pdic.core.albedo import albedo
from pdic.core.hit_radiance import (HitGrid, build_hit_grid, cell_albedo, cell_triangles, grid_points, grid_sides,
                                    open_cells)
from pdic.core.pipeline import bake
from pdic.core.rays import RayCaster
from pdic.core.scene import PointLight
from pdic.core.settings import Deviations, preset

from scenes import box_faces, quad, quad_scene


def _barycentric(positions, triangle, q):
    e1 = positions[triangle, 1] - positions[triangle, 0]
    e2 = positions[triangle, 2] - positions[triangle, 0]
    m = np.stack([e1, e2], axis=2)
    return np.array([np.linalg.lstsq(m[k], q[k] - positions[triangle[k], 0], rcond=None)[0] for k in range(len(q))])


def test_each_cell_centroid_reads_its_own_cell_on_either_side():
    rng = np.random.default_rng(0)
    positions = rng.random((40, 3, 3))
    L = rng.integers(1, 9, 40)
    offset, triangle, q = grid_points(positions, L)
    assert len(q) == int((L * L).sum())
    uv = _barycentric(positions, triangle, q)
    assert uv.min() > 0 and uv.sum(axis=1).max() < 1  # centroids lie inside their triangle
    E = np.zeros((2, len(q), 3), np.float32)
    E[0, :, 0] = np.arange(len(q))
    E[1, :, 1] = np.arange(len(q))
    grid = HitGrid(L, offset, E, E, q)
    front, centroid, _, _ = grid.lookup(triangle, uv, np.zeros(len(q), bool))
    back, _, _, _ = grid.lookup(triangle, uv, np.ones(len(q), bool))
    assert np.allclose(centroid, q)
    assert np.array_equal(front[:, 0], np.arange(len(q))) and not front[:, 1].any()
    assert np.array_equal(back[:, 1], np.arange(len(q))) and not back[:, 0].any()
    # Hits on a triangle's edges and corners (u + v = 1, u = 0, v = 0) land in one of its cells.
    edge = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.5, 0.5], [1.0 + 1e-9, -1e-9]])
    tri = np.zeros(len(edge), np.int64)
    cell = grid.lookup(tri, edge, np.zeros(len(edge), bool))[0][:, 0]
    assert np.all((cell >= offset[0]) & (cell < offset[0] + L[0] ** 2))


def test_the_grid_is_kept_within_its_budget():
    positions = np.array([[[0, 0, 0], [10.0, 0, 0], [0, 10.0, 0]]] * 3)
    L = grid_sides(positions, 0.01, budget=3000)
    assert int((L * L).sum()) <= 3000 and L.min() >= 1


def test_a_cell_holds_the_direct_light_of_its_centroid_and_nothing_behind():
    """A floor 1 m under a 100 W point light: E = P / (4 pi d^2) cos at each cell's centroid."""
    lamp = PointLight("lamp", np.array([0.5, 0.5, 1.0]), np.full(3, 100.0))
    scene = quad_scene([quad([0, 0, 0], [1, 0, 0], [0, 1, 0])], {"floor": (0, 8)}, [lamp])
    caster = RayCaster(scene.geometry.positions, scene.extent, make_executor(1), scene.geometry.transmission)

    def no_indirect(q, n, known):
        return np.zeros((len(q), 3)), np.zeros((len(q), 3)), 0, np.full((2, len(q)), -2)

    grid, counters = build_hit_grid(scene, caster, no_indirect, R_min=0.1, hits=10_000, seed=0, stream=[14, 0],
                                    executor=make_executor(1), progress=None)
    assert counters["hit_grid_cells"] == grid.E.shape[1] > 2
    offset, triangle, q = grid_points(scene.geometry.positions, grid.side)
    n = caster.face_normals[triangle]
    light = scene.lights[0].position
    to_light = light - q
    d = np.linalg.norm(to_light, axis=1)
    facing = np.einsum("ij,ij->i", to_light / d[:, None], n)
    expected = 100.0 / (4 * np.pi * d ** 2) * np.abs(facing)
    lit = 0 if (facing > 0).all() else 1  # the side that faces the lamp
    assert np.allclose(grid.E[lit, :, 0], expected, rtol=1e-5)
    assert not grid.E[1 - lit].any()


def test_a_cell_a_wall_crosses_is_closed_and_one_clear_of_it_open():
    """A 1 m floor with a 1 mm wall standing across it at x = 0.43 (deviation: open-cells): on the floor's
    top side the cells the wall crosses are closed (a hit there must test whether it sees the centroid),
    the others open; underneath, where nothing stands, every cell is open. Cells of the wall itself
    stand on the floor, at their triangles' edges, and are open."""
    floor = quad([0, 0, 0], [1, 0, 0], [0, 1, 0])
    wall = np.concatenate([quad([0.43, 0, 0], [0, 1, 0], [0, 0, 0.5]), quad([0.431, 0, 0], [0, 0, 0.5], [0, 1, 0])])
    positions = np.concatenate([floor, wall])
    caster = RayCaster(positions, executor=make_executor(1))
    L = np.array([10, 10, 4, 4, 4, 4])
    offset, triangle, q = grid_points(positions, L)
    opened = open_cells(positions, caster, L, offset, triangle, q, make_executor(1), None)
    on_floor = triangle < 2
    # Cells 0.1 m across: a wall within 1.2 cm of a centroid runs through its three segments' triangle
    # (whose inradius is 0.9 x the cell's, 2.6 cm or more); one 10 cm off misses them all.
    crossed = on_floor & (np.abs(q[:, 0] - 0.4305) < 0.012)
    far = on_floor & (np.abs(q[:, 0] - 0.4305) > 0.1)
    up = 0 if caster.face_normals[0, 2] > 0 else 1
    assert crossed.sum() >= 10 and far.sum() >= 100
    assert not opened[up, crossed].any()
    assert opened[up, far].all()
    assert opened[1 - up, on_floor].all()
    assert opened[:, ~on_floor].all()


def test_the_switch_builds_the_grid_and_the_hole_records_reuse_its_direct_light():
    lamp = PointLight("lamp", np.array([0.5, 0.5, 0.8]), np.full(3, 100.0))
    scene = quad_scene(box_faces(), {"floor": (0, 16), "back": (1, 16)}, [lamp])
    final = preset("FINAL", photons=4000, max_bounces=3, threads=1, hemisphere_theta=6, hemisphere_phi=12)
    on = bake(scene, final).stats["counters"]
    off = bake(scene, replace(final, deviations=Deviations(hit_grid=False))).stats["counters"]
    assert on["hit_grid_cells"] > 0
    # The hole records' grid reads the refined records but reuses pass 3's direct light.
    assert on["holes_hit_grid_cells"] == on["hit_grid_cells"] and on["holes_hit_grid_shadow_rays"] == 0
    assert "hit_grid_cells" not in off and "holes_hit_grid_cells" not in off


def test_a_cell_holds_the_mean_albedo_over_it():
    """Plain material: its base colour exactly. A texture ramping linearly in u: the cell centroid's
    value (a four-point rule symmetric about the centroid is exact for linear albedo). A checker of
    about one square per cell: closer to the cell's mean (dense sampling) than the centroid alone."""
    tris = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]] * 3, float)
    uvs = np.array([[[0.1, 0.1], [0.9, 0.1], [0.1, 0.9]], [[0.1, 0.1], [0.9, 0.1], [0.1, 0.9]],
                    [[0, 0], [5.3, 0], [0, 5.3]]], np.float32)
    ramp = np.repeat(np.linspace(0, 1, 256, dtype=np.float32)[None, :, None], 4, axis=0).repeat(3, axis=2)
    checker = np.array([[[1, 1, 1], [0, 0, 0]], [[0, 0, 0], [1, 1, 1]]], np.float32)
    geometry = sc.Geometry(tris, np.tile([0, 0, 1.0], (3, 3, 1)), uvs, np.array([0, 1, 2]), np.zeros(3))
    materials = sc.Materials(("plain", "ramp", "checker"), np.array([[0.2, 0.4, 0.6], [1, 1, 1], [1, 1, 1]]),
                             np.array([-1, 0, 1]), np.zeros((3, 3)))
    scene = sc.Scene(geometry, materials,
                     textures=(sc.Texture("ramp", ramp, "Linear"), sc.Texture("checker", checker, "Closest")))
    L = np.array([4, 4, 4])
    offset, triangle, q = grid_points(tris, L)
    rho = cell_albedo(scene, L, offset, triangle, make_executor(1), None)[:, 0]
    at_centroid = albedo(scene, triangle, _barycentric(tris, triangle, q))[:, 0]
    plain, ramp_cells, checker_cells = (triangle == t for t in range(3))
    assert np.all(rho[plain] == np.float32(0.2))
    assert np.allclose(rho[ramp_cells], at_centroid[ramp_cells], atol=1e-5)
    # The checker cells' mean: points drawn over the triangle, binned into the cells they fall in.
    uv = np.random.default_rng(1).random((200_000, 2))
    uv = np.where(uv.sum(axis=1, keepdims=True) > 1, 1 - uv, uv)
    tri = np.full(len(uv), 2)
    E = np.zeros((2, len(q), 3), np.float32)
    E[0, :, 0] = np.arange(len(q))
    cell = HitGrid(L, offset, E, E, q).lookup(tri, uv, np.zeros(len(uv), bool))[0][:, 0].astype(int)
    truth = np.bincount(cell, albedo(scene, tri, uv)[:, 0], len(q)) / np.maximum(np.bincount(cell, minlength=len(q)), 1)
    error = np.abs(rho - truth)[checker_cells].mean()
    assert error < 0.6 * np.abs(at_centroid - truth)[checker_cells].mean()


def test_a_record_just_in_front_of_a_wall_reads_the_wall_behind_it_not_a_cell_in_the_open():
    """A 10 cm plate 2 cm in front of a lit 2 m wall, facing it: much of what the plate's back sees is the
    wall's patch in the plate's shadow. The wall's grid cells (~40 cm) are larger than the plate, their
    centroids in the open; hits that near their record are shaded on their own, so the plate's indirect
    light stays near what per-hit shading (the hit grid off) gives it: 1.26x, against 1.92x when every
    hit that sees its cell's centroid reads the cell."""
    lamp = PointLight("lamp", np.array([0.0, -2.0, 0.0]), np.full(3, 300.0))
    wall = quad([-1, 0, -1], [2, 0, 0], [0, 0, 2])  # normal -y, toward the lamp
    plate = quad([-0.05, -0.02, -0.05], [0, 0, 0.1], [0.1, 0, 0])  # normal +y, toward the wall
    scene = quad_scene([wall, plate], {"wall": (0, 4), "plate": (1, 4)}, [lamp])
    final = preset("FINAL", photons=40_000, threads=1, hemisphere_theta=8, hemisphere_phi=16)
    grid = bake(scene, final)
    per_hit = bake(scene, replace(final, deviations=Deviations(hit_grid=False)))
    assert grid.stats["counters"]["hit_grid_cells"] > 0

    def plate_light(result):
        return float(result.indirect["plate"][result.coverage["plate"]].mean())

    assert plate_light(per_hit) > 0
    assert 0.8 < plate_light(grid) / plate_light(per_hit) < 1.5


def test_one_k_nearest_query_answers_the_nearest_of_points_asked_on_both_sides():
    """The hit grid asks both sides of a centroid, one side after the other: each side's points get their k nearest
    in one query, which answers their nearest too, the same photons a fresh query finds."""
    from scipy.spatial import cKDTree

    from pdic.core.density import PhotonDensity
    from pdic.core.photon_fallback import NearestPhotons
    from pdic.core.photons import PhotonMap

    rng = np.random.default_rng(4)
    count = 3000
    n = rng.normal(size=(count, 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    photons = PhotonMap(p=rng.uniform(-1, 1, (count, 3)).astype(np.float32), n=n, wi=n,
                        power=np.ones((count, 3), np.float32), d_prev=np.ones(count, np.float32),
                        prev=np.full(count, -1, np.int32), bounce=np.ones(count, np.uint8),
                        triangle=np.zeros(count, np.int32), albedo=np.full((count, 3), 0.5, np.float32),
                        emitted=count)
    density = PhotonDensity(photons)
    q = np.random.default_rng(5).uniform(-1, 1, (400, 3))
    front, back = np.arange(0, 300), np.arange(100, 400)
    neighbours = NearestPhotons(density, q)
    neighbours.expect_k(front)
    neighbours.expect_k(back)  # rows 100-299 are answered already
    _, nearest = cKDTree(density.p).query(q, k=1)
    _, k_nearest = cKDTree(density.p).query(q, k=neighbours.k)
    assert np.array_equal(neighbours.nearest(np.arange(400)), nearest)
    assert np.array_equal(neighbours.k_nearest(np.arange(100, 300)), k_nearest[100:300])
    # The fallback asks one side's points for their k nearest up front: the first is their nearest.
    one_side = NearestPhotons(density, q)
    one_side.expect_k(np.arange(50, 250))
    assert np.array_equal(one_side._tables[1][50:250, 0], nearest[50:250])
    assert (one_side._tables[1][:50] == -1).all() and (one_side._tables[1][250:] == -1).all()
    # Photons in coincident pairs: the two queries may order a tie otherwise, but find a photon as near.
    twin = np.repeat(np.arange(count), 2)
    twins = PhotonDensity(PhotonMap(**{f: getattr(photons, f)[twin] for f in ("p", "n", "wi", "power", "d_prev", "prev",
                                                                              "bounce", "triangle", "albedo")},
                                    emitted=2 * count))
    tied = NearestPhotons(twins, q)
    tied.expect_k(np.arange(400))

    def distance(picks):
        return np.linalg.norm(twins.p[picks].astype(np.float64) - q, axis=1)

    assert np.array_equal(distance(tied.nearest(np.arange(400))), distance(cKDTree(twins.p).query(q, k=1)[1]))


def _hit_grid(rng, T: int) -> HitGrid:
    """A grid of random sides 1-8 over T triangles, random values in its cells."""
    side = rng.integers(1, 9, T)
    offset, _ = cell_triangles(side)
    V = int((side * side).sum())
    return HitGrid(side, offset, rng.random((2, V, 3), dtype=np.float32), rng.random((2, V, 3), dtype=np.float32),
                   rng.normal(size=(V, 3)))


def test_a_hit_just_past_the_far_edge_reads_its_own_triangles_cell():
    """u + v a rounding past 1 in a grid's top row: the cell is the row's last, not the next triangle's first
    (on the last triangle the lookup raised IndexError)."""
    rng = np.random.default_rng(15)
    grid = _hit_grid(rng, T=3)
    last = len(grid.side) - 1
    L, first = int(grid.side[last]), int(grid.offset[last])
    bary = np.array([[0.05 + 1e-9, 0.95], [np.nextafter(0.5, 1.0), 0.5]])  # u + v just over 1
    _, centroid, _, _ = grid.lookup(np.array([last, last]), bary, np.zeros(2, bool))
    cells = [int(np.flatnonzero((grid.centroid == c).all(axis=1))[0]) for c in centroid]
    assert all(first <= c < first + L * L for c in cells), (cells, first, L)


def test_a_grid_keeps_its_centroids_albedos_and_open_cells_in_one_aligned_table():
    """One 64-byte row a cell (the kernel reads a cell's line once); the arrays a grid was given become views of
    it, a later grid over the same cells shares it, and a grid shipped to a Dask worker arrives with one table."""
    import pickle

    from pdic.core.hit_radiance import CELL

    rng = np.random.default_rng(16)
    grid = _hit_grid(rng, T=50)
    V = len(grid.centroid)
    centroid, albedo, opened = grid.centroid.copy(), rng.random((V, 3), dtype=np.float32), rng.random((2, V)) < 0.5
    grid = HitGrid(grid.side, grid.offset, grid.E, grid.E_direct, centroid, albedo, None, opened)
    assert grid.cells.dtype == CELL and CELL.itemsize == 64 and grid.cells.ctypes.data % 64 == 0
    assert np.array_equal(grid.centroid, centroid) and np.array_equal(grid.albedo, albedo)
    assert np.array_equal(grid.open, opened) and grid.open.dtype == bool and grid.open.shape == (2, V)
    for view in (grid.centroid, grid.albedo, grid.open):
        assert np.shares_memory(view, grid.cells)
    later = HitGrid(grid.side, grid.offset, grid.E * 2, grid.E_direct, grid.centroid, grid.albedo, None, grid.open,
                    grid.cells)
    assert later.cells is grid.cells
    reopened = ~opened  # cells found open anew: a table of its own, the first grid's untouched
    other = HitGrid(grid.side, grid.offset, grid.E, grid.E_direct, grid.centroid, grid.albedo, None, reopened,
                    grid.cells)
    assert other.cells is not grid.cells and np.array_equal(other.open, reopened)
    assert np.array_equal(grid.open, opened)
    bare = HitGrid(grid.side, grid.offset, grid.E, grid.E_direct, centroid)  # no albedo, no open cells
    assert bare.albedo is None and bare.open is None and not bare.cells["albedo"].any()
    shipped = pickle.loads(pickle.dumps(grid))
    assert len(pickle.dumps(grid)) < V * (CELL.itemsize + 2 * 24) + 10_000  # the table once, no copies of its views
    for name in ("centroid", "albedo", "open", "E"):
        assert np.array_equal(getattr(shipped, name), getattr(grid, name)), name
    assert np.shares_memory(shipped.centroid, shipped.cells) and np.shares_memory(shipped.open, shipped.cells)
    assert shipped.cells.ctypes.data % 64 == 0  # wherever the unpickler put the table
    triangle = rng.integers(0, len(grid.side), 500)
    bary, back = rng.random((500, 2)) * 0.5, rng.random(500) < 0.5
    for a, b in zip(grid.lookup(triangle, bary, back), shipped.lookup(triangle, bary, back)):
        assert np.array_equal(a, b)
