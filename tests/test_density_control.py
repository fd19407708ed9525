"""Section 3.4 density control (Equation 4 with [SW00]'s redistribution): power kept, photons per zone bounded."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from pdic.core.density_control import control_density, harmonic_last_hit_radius
from pdic.core.executor import Executor
from pdic.core.photons import trace_photons
from pdic.core.rays import RayCaster
from pdic.core.scene import PointLight

from scenes import box_faces, quad_scene

N_ZONE, A, R_NEAREST, R_MIN, R_MAX = 24, 0.4, 16, 0.02, 0.17


@pytest.fixture(scope="module")
def box_photons():
    """A closed unit box (albedo 0.7) lit by a point light near its floor: dense direct photons under it."""
    scene = quad_scene(box_faces(), {}, (PointLight("lamp", np.array([0.5, 0.5, 0.15]), np.full(3, 10.0)),))
    photons, _ = trace_photons(scene, RayCaster(scene.geometry.positions), 60_000, 64, seed=2, executor=Executor(2))
    return photons


def _per_zone(photons, R, samples=2000):
    """Photons of the same class on the same surface within a R of ``samples`` random photons
    (their zones of influence, were records placed there)."""
    pick = np.random.default_rng(0).choice(len(photons), min(samples, len(photons)), replace=False)
    counts = []
    for bounced in (False, True):
        members = np.flatnonzero(photons.is_indirect == bounced)
        tree = cKDTree(photons.p[members])
        at = pick[photons.is_indirect[pick] == bounced]
        for i, near in zip(at, tree.query_ball_point(photons.p[at], A * R[at])):
            counts.append(int((photons.n[members[near]] @ photons.n[i] > 0.7).sum()))
    return np.array(counts)


def test_density_control_keeps_total_photon_power(box_photons):
    controlled, stats = control_density(box_photons, N_ZONE, A, R_NEAREST, R_MIN, R_MAX, seed=0)
    assert stats.kept == len(controlled) < 0.8 * len(box_photons)  # it does discard
    assert stats.redistributed == len(box_photons) - len(controlled)
    for bounced in (False, True):  # direct and indirect power each kept (they serve different passes)
        before = box_photons.power[box_photons.is_indirect == bounced].astype(np.float64).sum(0)
        after = controlled.power[controlled.is_indirect == bounced].astype(np.float64).sum(0)
        assert np.allclose(after, before, rtol=0.01)
    assert np.all(np.isfinite(controlled.power))


def test_density_control_bounds_photons_per_zone(box_photons):
    R = harmonic_last_hit_radius(box_photons.p, box_photons.n, box_photons, R_NEAREST, R_MIN, R_MAX)
    before = _per_zone(box_photons, R)
    controlled, _ = control_density(box_photons, N_ZONE, A, R_NEAREST, R_MIN, R_MAX, seed=0)
    R_after = harmonic_last_hit_radius(controlled.p, controlled.n, controlled, R_NEAREST, R_MIN, R_MAX)
    after = _per_zone(controlled, R_after)
    assert np.percentile(before, 90) > 4 * N_ZONE  # the uncontrolled map crowds its zones
    assert np.percentile(after, 90) <= 2 * N_ZONE  # Equation 4: about n per zone, not more
    assert np.median(after) >= N_ZONE / 4  # and not emptied


def test_density_control_path_links_stay_valid(box_photons):
    controlled, _ = control_density(box_photons, N_ZONE, A, R_NEAREST, R_MIN, R_MAX, seed=0)
    linked = controlled.prev >= 0
    assert np.all(controlled.prev < len(controlled))
    # a link reaches the previous hit or, if that photon was discarded, a photon of the same kind near it
    gap = np.linalg.norm(controlled.p[controlled.prev[linked]] - controlled.last_hit[linked], axis=1)
    assert np.percentile(gap, 99) < 2 * A * R_MAX
