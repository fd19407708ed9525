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
from pdic.core.rays import RayCaster
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
    deviations = Deviations(virtual_thinning=False, zone_visibility=False, harmonic_cell_radiance=harmonic,
                            path_visibility=False, virtual_cell_minimum=False)
    sources = GatherSources(PhotonDensity(photons), PhotonLighting.zeros(len(photons)), None, radiance_out,
                            deviations)
    sums = CellSums(1, H)
    virtual, cells_filled, rays, _ = fill_virtual(None, sources, frames, np.array([3]), np.array([3, 4, 5]),
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


def _fill(caster, **switches):
    photons, radiance_out, frames = _paths()
    deviations = Deviations(virtual_thinning=False, zone_visibility=False, **switches)
    sources = GatherSources(PhotonDensity(photons), PhotonLighting.zeros(len(photons)), None, radiance_out,
                            deviations)
    sums = CellSums(1, H)
    counts = fill_virtual(caster, sources, frames, np.array([3]), np.array([3, 4, 5]), np.full(1, np.inf), sums,
                          np.random.default_rng(0))
    return counts, sums


def test_a_cell_only_one_virtual_ray_reached_is_left_to_a_real_ray():
    """virtual-cell-minimum: cell 6 holds one photon's radiance, a one-sample estimate; cell 1 keeps its two."""
    (virtual, cells_filled, _, _), sums = _fill(None, path_visibility=False, virtual_cell_minimum=True)
    assert (virtual, cells_filled) == (2, 1)
    assert sums.count[6] == 0 and sums.count[1] > 0
    assert 6 in sums.empty_cells()


def test_a_virtual_ray_whose_previous_hit_the_record_cannot_see_is_dropped():
    """path-visibility: a small plate halfway along cell 6's path hides its previous hit from the
    record (the photon beside it saw it); cell 1's paths stay open. One occlusion ray per path."""
    photons, _, _ = _paths()
    target = photons.p[2].astype(np.float64)  # cell 6's previous hit, 1 m from the record
    mid, axis = 0.5 * target, target / np.linalg.norm(target)
    u = np.cross(axis, [1.0, 0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    plate = np.array([[mid + 0.05 * (-u - v), mid + 0.05 * (u - v), mid + 0.05 * v]])
    caster = RayCaster(plate, extent=2.0)
    (virtual, cells_filled, _, path_rays), sums = _fill(caster, path_visibility=True, virtual_cell_minimum=False)
    assert path_rays == 3
    assert (virtual, cells_filled) == (2, 1)
    assert sums.count[6] == 0 and sums.count[1] == pytest.approx(2.0)
    (virtual, cells_filled, _, _), _ = _fill(caster, path_visibility=False, virtual_cell_minimum=False)
    assert (virtual, cells_filled) == (3, 2)
