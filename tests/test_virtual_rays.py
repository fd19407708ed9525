"""Figure 4a-b in closed form: virtual rays from a hand-made set of photon paths fill known cells.

A record at the origin facing +z, a 2 x 4 cell hemisphere (8 equal cosine-weighted cells), and
three photons on the floor beside it whose previous hits lie straight along known cell centres:
two paths through cell 1 whose previous photons leave radiance 1 and 3, one through cell 6 with
radiance 2. With equal photon powers the flux-weighted harmonic mean makes cell 1 hold
2 / (1/1 + 1/3) = 1.5 (the plain mean, the switch off, 2); E = pi / 8 x (sum of cell radiances).
"""
from __future__ import annotations

import numpy as np
import pytest

from pdic.core.density import PhotonDensity
from pdic.core.gather_cells import CellSums
from pdic.core.hemisphere import Hemisphere, local_frames
from pdic.core.photons import PhotonLighting, PhotonMap
from pdic.core.refinement import GatherSources
from pdic.core.settings import Deviations
from pdic.core.virtual_rays import fill_virtual

H = Hemisphere(2, 4)
CELLS = (1, 1, 6)
L_PREV = (1.0, 3.0, 2.0)


def _paths():
    """Photon map: 3 previous photons (sources, prev -1) then 3 floor photons linked to them."""
    n_k = np.array([[0.0, 0, 1]])
    t1, t2, n = local_frames(n_k)
    w_local = H.sample_cells(np.array(CELLS), np.full((3, 2), 0.5))  # cell centres
    w_world = w_local[:, :1] * t1 + w_local[:, 1:2] * t2 + w_local[:, 2:3] * n
    floor = np.array([[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [-0.01, 0.0, 0.0]])
    last_hit = w_world * 1.0  # the previous hits, 1 m from the record along each cell centre
    p = np.concatenate([last_hit, floor])
    to_prev = np.concatenate([-w_world, last_hit - floor])
    d_prev = np.linalg.norm(to_prev, axis=1)
    up = np.tile([0.0, 0, 1], (6, 1))
    photons = PhotonMap(p=p.astype(np.float32), n=up.astype(np.float32),
                        wi=(to_prev / d_prev[:, None]).astype(np.float32), power=np.ones((6, 3), np.float32),
                        d_prev=d_prev.astype(np.float32), prev=np.array([-1, -1, -1, 0, 1, 2], np.int32),
                        bounce=np.array([0, 0, 0, 1, 1, 1], np.uint8), triangle=np.zeros(6, np.int32),
                        albedo=np.full((6, 3), 0.5, np.float32), emitted=3)
    radiance_out = np.zeros((6, 3))
    radiance_out[:3] = np.array(L_PREV)[:, None]
    return photons, radiance_out, (np.zeros((1, 3)), t1, t2, n)


@pytest.mark.parametrize("harmonic, cell_1", [(True, 1.5), (False, 2.0)])
def test_virtual_rays_fill_the_cells_of_their_paths_with_the_linked_photons_radiance(harmonic, cell_1):
    photons, radiance_out, frames = _paths()
    deviations = Deviations(virtual_thinning=False, zone_visibility=False, harmonic_cell_radiance=harmonic)
    sources = GatherSources(PhotonDensity(photons), PhotonLighting.zeros(len(photons)), None, radiance_out,
                            deviations)
    sums = CellSums(1, H)
    virtual, cells_filled, rays = fill_virtual(None, sources, frames, np.array([3]), np.array([3, 4, 5]),
                                               np.full(1, np.inf), sums, np.random.default_rng(0))
    assert (virtual, cells_filled, rays) == (3, 2, 0)
    L_cell = sums.L_sum[:, 0] / np.maximum(sums.count, 1)
    expected = np.zeros(H.cells)
    expected[1], expected[6] = cell_1, 2.0
    np.testing.assert_allclose(L_cell, expected, rtol=1e-12)
    np.testing.assert_allclose(sums.r_min[[1, 6]], 1.0, rtol=1e-6)  # the previous hits lie 1 m away
    E, _, _, R = sums.irradiance_and_gradients(*frames[1:], r_floor=1e-6)
    np.testing.assert_allclose(E[0], np.pi / H.cells * (cell_1 + 2.0), rtol=1e-12)
    assert R[0] == pytest.approx(1.0, rel=1e-6)  # harmonic mean of the three rays' distances
