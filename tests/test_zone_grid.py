"""The zone grid finds exactly the (point, record) pairs Equation 2's zone test accepts."""
import numpy as np
import pytest

from pdic.core.hole_records import _Placed
from pdic.core.irradiance_cache import _NeighbourClamp
from pdic.core.zone_grid import (CELL_PER_ZONE, DENSE_CELL_PER_ZONE, JoinedZoneGrid, SharedZones, ZoneGrid,
                                 cell_per_zone)


def brute_pairs(q, p, zone):
    d2 = ((q[:, None, :] - p[None, :, :]) ** 2).sum(axis=2)
    rows, recs = np.nonzero(d2 <= zone[None, :] ** 2)
    return rows, recs


@pytest.mark.parametrize("cell", [CELL_PER_ZONE, DENSE_CELL_PER_ZONE])
@pytest.mark.parametrize("spread", [1.0, 30.0, 1e4])
def test_pairs_are_exactly_the_points_inside_each_zone(spread, cell):
    """Zones from 0.01 m up to ``spread`` times that (a few huge R_k beside many small ones), at both cell
    sizes a lookup picks: the pairs, and their order, do not depend on it."""
    rng = np.random.default_rng(7)
    p = rng.random((400, 3)) * 10.0
    zone = 0.01 * np.exp(rng.random(400) * np.log(spread)) + 0.3 * rng.random(400)
    q = np.concatenate([rng.random((3000, 3)) * 12.0 - 1.0, p[:50] + 1e-3])  # some outside, some on records
    rows, recs = ZoneGrid(p, zone, cell).pairs(q)
    want_rows, want_recs = brute_pairs(q, p, zone)
    assert len(rows) == len(want_rows) > 0
    got = np.sort(rows * len(p) + recs)
    assert np.array_equal(got, np.sort(want_rows * len(p) + want_recs))
    # Grouped by point, points ascending, each point's records ascending: Equation 3's sum order.
    assert np.all(np.diff(rows * len(p) + recs) > 0)


def _records(rng, K=500):
    p = rng.random((K, 3)) * 3.0
    return p, 0.05 + rng.random(K) * 1.5  # R_k


@pytest.mark.parametrize("cell", [CELL_PER_ZONE, DENSE_CELL_PER_ZONE])
def test_a_shared_grid_joined_with_appended_records_lists_the_pairs_of_one_grid(cell):
    """Every target's lookups start from pass 3's records, then append the target's hole records: the shared
    grid, joined with a grid over the appended ones, lists the same pairs in the same order as one grid
    over all (so Equation 3 sums the same terms in the same order)."""
    rng = np.random.default_rng(3)
    a = 0.4
    p, R = _records(rng)
    q = np.concatenate([rng.random((4000, 3)) * 4.0 - 0.5, p[::7] + 1e-4])
    shared = SharedZones(p[:350], R[:350], a)
    for K in (350, 351, 500):  # the shared records alone, one appended, many appended
        zone = a * np.asarray(R[:K], np.float64)
        grid = shared.grid(p[:K], zone, cell)
        assert isinstance(grid, ZoneGrid if K == 350 else JoinedZoneGrid)
        want = ZoneGrid(p[:K], zone, cell).pairs(q)
        got = grid.pairs(q)
        assert len(want[0]) > 1000
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
    assert shared.grid(p[:350], a * R[:350]) is shared.grid(p[:400], a * R[:400]).parts[0][0]  # built once
    # Records that do not begin with the shared ones (a moved record) get a grid of their own, still exact.
    moved = p.copy()
    moved[10] += 0.5
    got = shared.grid(moved, a * R)
    assert isinstance(got, ZoneGrid) and got is not shared.grid(p[:350], a * R[:350])
    want = ZoneGrid(moved, a * R).pairs(q)
    assert all(np.array_equal(x, y) for x, y in zip(got.pairs(q), want))


def test_neighbour_clamping_against_a_shared_tree_clamps_the_same():
    """Hole records are clamped against every record placed before them (R_k <= R_j + |p_k - p_j|); with
    the bake's shared kd-tree over pass 3's records and one over the target's earlier rounds the radii
    are the same, to the bit, as with one tree over all."""
    rng = np.random.default_rng(5)
    p, R = _records(rng, 800)
    shared = SharedZones(p[:600], R[:600], 0.4)
    existing = _Placed(p, R)
    new_p, new_R = rng.random((300, 3)) * 3.0, 0.2 + rng.random(300) * 2.0
    want = _NeighbourClamp(existing).clamp(new_p, new_R)
    got = _NeighbourClamp(existing, shared=shared)
    assert got.levels[0][2] is shared.clamp_level()[2]
    assert np.array_equal(got.clamp(new_p, new_R), want) and (want < new_R).sum() > 100


def test_finer_cells_where_many_points_query_each_record():
    assert cell_per_zone(points=3_200_000, records=28_000) == DENSE_CELL_PER_ZONE  # Preview's fine texel samples
    assert cell_per_zone(points=45_000, records=154_000) == CELL_PER_ZONE  # a hole round over Final's records


def test_zero_zones_and_empty_inputs():
    p = np.array([[0.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0]])
    rows, recs = ZoneGrid(p, np.zeros(3)).pairs(np.array([[1.0, 0, 0], [0.5, 0, 0]]))
    assert rows.tolist() == [0, 0] and recs.tolist() == [1, 2]  # a point exactly on a zero zone
    assert len(ZoneGrid(np.zeros((0, 3)), np.zeros(0)).pairs(np.ones((4, 3)))[0]) == 0
    assert len(ZoneGrid(p, np.ones(3)).pairs(np.zeros((0, 3)))[0]) == 0


def test_non_finite_points_match_nothing():
    rows, _ = ZoneGrid(np.zeros((1, 3)), np.ones(1)).pairs(np.array([[np.nan, 0, 0], [np.inf, 0, 0], [0.0, 0, 0]]))
    assert rows.tolist() == [2]


def test_spatial_order_is_a_z_curve_permutation():
    from pdic.core.zone_grid import spatial_order

    corners = np.array([[x, y, z] for z in (0.0, 1.0) for y in (0.0, 1.0) for x in (0.0, 1.0)])
    shuffled = np.random.default_rng(3).permutation(8)
    order = spatial_order(corners[shuffled])
    # The Z-curve visits a cube's corners x fastest, then y, then z.
    assert np.array_equal(corners[shuffled][order], corners)
    p = np.random.default_rng(4).random((1000, 3))
    p[5] = np.nan
    assert np.array_equal(np.sort(spatial_order(p)), np.arange(1000))
    assert len(spatial_order(np.zeros((0, 3)))) == 0
