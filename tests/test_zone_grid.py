"""The zone grid finds exactly the (point, record) pairs Equation 2's zone test accepts."""
import numpy as np
import pytest

from pdic.core.zone_grid import CELL_PER_ZONE, DENSE_CELL_PER_ZONE, ZoneGrid, cell_per_zone


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
