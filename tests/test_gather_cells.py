"""CellSums: real rays written into their distinct cells in place sum exactly what the general
bincount path sums (pass 3 relies on it for bit-identical records)."""
import numpy as np

from pdic.core.gather_cells import CellSums
from pdic.core.hemisphere import Hemisphere


def test_real_rays_in_place_give_the_same_sums_as_add_rays_bit_for_bit():
    H = Hemisphere(4, 8)
    rng = np.random.default_rng(3)
    B = 5
    cells = rng.permutation(B * H.cells)[:100]  # distinct cells, as probe and empty-cell rays are
    w_local = H.sample_cells(cells % H.cells, rng.random((len(cells), 2)))
    dist = np.where(rng.random(len(cells)) < 0.2, np.inf, rng.random(len(cells)) * 3)
    L = np.where(np.isfinite(dist)[:, None], rng.random((len(cells), 3)), 0.0)
    general, in_place = CellSums(B, H), CellSums(B, H)
    general.add_rays(cells, L, w_local, dist)
    in_place.add_real_rays(cells, w_local, dist)
    in_place.add_real_radiance(cells[np.isfinite(dist)], L[np.isfinite(dist)])
    for name in ("L_sum", "rot_sum", "count", "r_min"):
        assert np.array_equal(getattr(general, name), getattr(in_place, name)), name
    assert np.count_nonzero(in_place.count) == len(cells)


def _cells_with_radiance(L_cell: np.ndarray, H: Hemisphere) -> CellSums:
    """CellSums of B records whose C cells each hold one ray of radiance L_cell (B, C) on every channel."""
    B = len(L_cell)
    sums = CellSums(B, H)
    cells = np.arange(B * H.cells)
    w_local = H.sample_cells(cells % H.cells, np.full((len(cells), 2), 0.5))
    sums.add_rays(cells, np.repeat(L_cell.reshape(-1, 1), 3, axis=1), w_local, np.ones(len(cells)))
    return sums


def test_a_uniform_hemisphere_has_no_standard_error():
    H = Hemisphere(8, 16)
    assert np.array_equal(_cells_with_radiance(np.full((3, H.cells), 2.5), H).standard_error(), np.zeros(3))


def test_the_standard_error_of_independent_cells_matches_the_spread_of_e():
    # Cells of i.i.d. radiance (mean 1, sd 0.5): E = pi/C sum L has sd pi/C sqrt(C) 0.5, which the
    # phi-neighbour pairs must estimate without bias (adaptive-gathering stops on it).
    H = Hemisphere(8, 16)
    L = np.random.default_rng(7).normal(1.0, 0.5, (4000, H.cells))
    sums = _cells_with_radiance(L, H)
    true_sd = H.cell_weight * np.sqrt(H.cells) * 0.5
    estimated = np.sqrt(np.mean(sums.standard_error() ** 2))
    assert abs(estimated / true_sd - 1) < 0.03
    E = H.cell_weight * L.sum(axis=1)
    assert abs(E.std() / true_sd - 1) < 0.05  # the spread the estimate stands for
