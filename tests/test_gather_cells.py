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
