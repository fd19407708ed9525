"""Pass 2 keeps every photon inside a record's zone after its final neighbour clamp (deviation: clamp-recovery).

Algorithm 1 stops once every photon is covered; the final min-plus clamp ([KBPZ06]) then shrinks
zones, and the photons it uncovers had only the nearest photon's stale estimate to lend pass 3's
gathering hits there (the cathedral: 35 % of its photons; a walkway's records gathered a wall above
it at 0.4x a path tracer's radiance and came out 25-31 % dark). Recovery places records for them.
"""
from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from pdic.core.density import PhotonDensity
from pdic.core.constants import STREAM_RECORD_ORDER
from pdic.core.irradiance_cache import CacheParameters, cache_from_photons, neighbour_clamp, place_records
from pdic.core.photons import trace_photons
from pdic.core.rays import RayCaster
from pdic.core.scene import PointLight
from pdic.core.ward import accepted, ward_weight

from scenes import lit, quad

PARAMS = CacheParameters(a=0.4, r_nearest=16, R_min=0.02, R_max=1.0, neighbour_clamp=True)


def _room():
    """A 2 x 2 floor, a wall standing on it and a low shelf before the wall, lit from above: zones
    of very different sizes side by side, which the final clamp shrinks."""
    tris = np.concatenate([quad([-1, -1, 0], [2, 0, 0], [0, 2, 0]), quad([0.3, -1, 0], [0, 2, 0], [0, 0, 1]),
                           quad([0.1, -1, 0.1], [0.2, 0, 0], [0, 2, 0])])
    scene = lit(tris, PointLight("p", np.array([-0.3, 0.0, 0.8]), np.full(3, 100.0)))
    caster = RayCaster(tris)
    photons, _ = trace_photons(scene, caster, 20_000, 3, seed=3)
    return caster, PhotonDensity(photons)


def _uncovered(density: PhotonDensity, cache) -> np.ndarray:
    """(N,) bool: photons no record accepts (Equation 2 and the in-front test), by brute force over the
    records whose zone reaches them."""
    p, n = density.p.astype(np.float64), density.n.astype(np.float64)
    covered = np.zeros(len(p), bool)
    tree = cKDTree(p)
    for k in range(len(cache)):
        near = np.array(tree.query_ball_point(cache.p[k], PARAMS.a * cache.R[k] * 1.001), np.int64)
        if len(near):
            w = ward_weight(p[near], n[near], cache.p[k], cache.n[k], cache.R[k])
            covered[near[accepted(w, PARAMS.a, p[near], n[near], cache.p[k], cache.n[k], cache.R[k])]] = True
    return ~covered


def test_every_photon_covered_after_the_clamp():
    caster, density = _room()
    plain, _, _, _ = cache_from_photons(density, PARAMS, seed=1, caster=caster)
    cache, zones, lighting, stats = cache_from_photons(density, replace(PARAMS, clamp_recovery=True), seed=1,
                                                       caster=caster)
    before, after = _uncovered(density, plain).mean(), _uncovered(density, cache).mean()
    assert before > 0.02, before  # the clamp does uncover photons here
    assert after < 0.005, (before, after)
    assert len(cache) > len(plain) and len(zones.parts) == len(cache)
    assert stats.uncovered_after_clamp[0] > 0.8 * before * len(density.p)
    # The clamp still holds over all records, old and new: R_k <= R_j + |p_k - p_j|.
    d = np.linalg.norm(cache.p[:, None] - cache.p[None], axis=2)
    assert np.all(cache.R[:, None] <= cache.R[None, :] + d + 1e-9)
    # The new records' weights joined the photons' sums: each photon's section 3.1 estimate stays finite.
    assert np.isfinite(lighting.E_indirect(np.arange(len(density.p)))).all()
    assert (lighting.w_sum >= 1 / PARAMS.a - 1e-4).mean() > 0.99


def test_recovery_off_is_the_plain_clamp():
    """Off, pass 2 is Algorithm 1's walk and one min-plus pass, nothing more."""
    caster, density = _room()
    off, _, _, stats = cache_from_photons(density, replace(PARAMS, clamp_recovery=False), seed=1, caster=caster)
    walked, _, _ = place_records(density, density.p, density.n, np.zeros(len(density.p)),
                                 np.zeros((len(density.p), 3)), PARAMS,
                                 np.random.default_rng([1, STREAM_RECORD_ORDER]), candidate_is_photon=True,
                                 caster=caster)
    assert len(off) == len(walked) and np.array_equal(off.p, walked.p)
    assert np.array_equal(off.R, neighbour_clamp(walked.p, walked.R)) and stats.uncovered_after_clamp == []


def test_coverage_after_the_clamp_is_the_same_with_the_library_or_without(monkeypatch):
    """Which photons the clamped zones still cover: the compiled Equations 1-2 (core/native_kernels.py) give
    numpy's verdict for every photon, and both the brute force's."""
    from pdic.core import native_kernels
    from pdic.core.irradiance_cache import covered_by_zones

    assert native_kernels.library() is not None, native_kernels.status()
    caster, density = _room()
    walked, zones, _ = place_records(density, density.p, density.n, np.zeros(len(density.p)),
                                     np.zeros((len(density.p), 3)), PARAMS,
                                     np.random.default_rng([1, STREAM_RECORD_ORDER]), candidate_is_photon=True,
                                     caster=caster)
    cache = replace(walked, R=neighbour_clamp(walked.p, walked.R))
    compiled = covered_by_zones(density, cache, zones, PARAMS.a, walked.R)
    monkeypatch.setattr(native_kernels, "library", lambda: None)
    plain = covered_by_zones(density, cache, zones, PARAMS.a, walked.R)
    assert np.array_equal(compiled, plain)
    assert 0.02 < (~plain).mean() < 0.5  # the clamp uncovers some, not most
    assert np.array_equal(plain, ~_uncovered(density, cache))
