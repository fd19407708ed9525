"""Algorithm 1 run in blocks places the records the sequential walk would (core/irradiance_cache.py).

The block walk decides many candidates at once; these tests hold it to the sequential walk's
outcome: no candidate left with w_sum < 1/a, no record's zone covering the centre of a record
placed after it, and about as many records and mutual coverings as a brute-force sequential walk.
"""
import numpy as np
import pytest

from pdic.core.density import PhotonDensity
from pdic.core.irradiance_cache import CacheParameters, IrradianceCache, place_records
from pdic.core.photons import trace_photons
from pdic.core.rays import RayCaster
from pdic.core.record_walls import beyond_wall
from pdic.core.scene import PointLight
from pdic.core.ward import accepted, ward_weight

from scenes import lit, quad

PARAMS = CacheParameters(a=0.5, r_nearest=16, R_min=0.02, R_max=0.4)


def _floor_and_wall():
    """A 2 x 2 floor at z = 0 with a wall standing on it (the plane x = 0.3), lit from x < 0.3."""
    tris = np.concatenate([quad([-1, -1, 0], [2, 0, 0], [0, 2, 0]), quad([0.3, -1, 0], [0, 2, 0], [0, 0, 1])])
    scene = lit(tris, PointLight("p", np.array([-0.3, 0.0, 0.8]), np.full(3, 100.0)))
    caster = RayCaster(tris)
    photons, _ = trace_photons(scene, caster, 12_000, 3, seed=3)
    return caster, PhotonDensity(photons)


def _covers(cache: IrradianceCache, j: np.ndarray, p: np.ndarray, n: np.ndarray, walls: bool) -> np.ndarray:
    """(m,) bool: record j accepts the point (p, n) (Equation 2, in-front test, optionally its walls)."""
    ok = accepted(ward_weight(p, n, cache.p[j], cache.n[j], cache.R[j]), PARAMS.a, p, n, cache.p[j], cache.n[j],
                  cache.R[j])
    if walls:
        ok &= ~beyond_wall(cache.wall[j], p - cache.p[j], cache.n[j])
    return ok


def _covered_centres(cache: IrradianceCache, walls: bool) -> tuple[int, int]:
    """(pairs j < k whose record j covers p_k, pairs j != k whose record j covers p_k)."""
    j, k = np.nonzero(~np.eye(len(cache), dtype=bool))
    hit = _covers(cache, j, cache.p[k], cache.n[k], walls)
    return int(np.sum(hit & (j < k))), int(hit.sum())


def _sequential_walk(density: PhotonDensity, p: np.ndarray, n: np.ndarray, order: np.ndarray) -> IrradianceCache:
    """Brute-force sequential Algorithm 1 (no walls): the reference the block walk is held to."""
    w_sum, P, N, R = np.zeros(len(p)), [], [], []
    for c in order:
        if w_sum[c] >= 1 / PARAMS.a:
            continue
        R_c = np.clip(density.harmonic_mean_distances(p[c][None], n[c][None], PARAMS.r_nearest, PARAMS.R_max),
                      PARAMS.R_min, PARAMS.R_max)[0]
        if R:
            R_c = min(R_c, float(np.min(np.array(R) + np.linalg.norm(np.array(P) - p[c], axis=1))))
        w = ward_weight(p, n, p[c], n[c], R_c)
        ok = accepted(w, PARAMS.a, p, n, p[c], n[c], R_c)
        w_sum[ok] += w[ok]
        w_sum[c] = max(w_sum[c], 1 / PARAMS.a)
        P.append(p[c]), N.append(n[c]), R.append(R_c)
    return IrradianceCache(p=np.array(P), n=np.array(N), E=np.zeros((len(P), 3)), R=np.array(R))


def test_block_walk_covers_every_photon_and_no_record_covers_a_later_centre():
    caster, density = _floor_and_wall()
    p, n = density.p, density.n.astype(np.float64)
    w_sum = np.zeros(len(p))
    cache, zones, _ = place_records(density, p, n, w_sum, np.zeros((len(p), 3)), PARAMS,
                                    np.random.default_rng(0), candidate_is_photon=True, caster=caster)
    assert np.all(w_sum >= 1 / PARAMS.a - 1e-12)  # Algorithm 1's loop condition holds nowhere
    assert len(zones.parts) == len(cache) > 50
    later, mutual = _covered_centres(cache, walls=False)
    assert later == 0  # every record sits at a candidate no earlier record covered
    reference = _sequential_walk(density, p, n, np.random.default_rng(0).permutation(len(p)))
    _, mutual_reference = _covered_centres(reference, walls=False)
    assert len(cache) == pytest.approx(len(reference), rel=0.1)
    assert mutual <= 1.1 * mutual_reference + 5


def test_hole_block_walk_covers_every_candidate_within_its_walls():
    caster, density = _floor_and_wall()
    g = np.linspace(-0.95, 0.95, 40)
    cand_p = np.stack([*np.meshgrid(g, g), np.zeros((40, 40))], axis=-1).reshape(-1, 3)
    cand_n = np.tile([0.0, 0.0, 1.0], (len(cand_p), 1))
    w_sum = np.zeros(len(cand_p))
    cache, _, _ = place_records(density, cand_p, cand_n, w_sum, np.zeros((len(cand_p), 3)), PARAMS,
                                np.random.default_rng(1), candidate_is_photon=False, existing=IrradianceCache(),
                                caster=caster)
    assert np.all(w_sum >= 1 / PARAMS.a - 1e-12)
    assert np.isfinite(cache.wall).any()  # records near x = 0.3 found the wall
    later, _ = _covered_centres(cache, walls=True)
    assert later == 0  # walls included: a candidate past an earlier record's wall may get its own record


def test_hole_records_left_to_final_gathering_skip_the_density_estimate_only():
    """Without the estimate (Final with standard gathering) the same records with the same radii and
    walls, E_k 0 and no zone photons; with it, E_k from the photons. One block: block sizes, which
    follow the zones' sizes, cannot differ."""
    from pdic.core.irradiance_cache import cache_for_holes

    caster, density = _floor_and_wall()
    g = np.linspace(-0.5, 0.5, 5)
    cand_p = np.stack([*np.meshgrid(g, g), np.zeros((5, 5))], axis=-1).reshape(-1, 3)
    cand_n = np.tile([0.0, 0.0, 1.0], (len(cand_p), 1))
    full, zones, _ = cache_for_holes(density, cand_p, cand_n, PARAMS, np.random.default_rng(2), IrradianceCache(),
                                     caster)
    bare, no_zones, _ = cache_for_holes(density, cand_p, cand_n, PARAMS, np.random.default_rng(2), IrradianceCache(),
                                        caster, estimate=False)
    for name in ("p", "n", "R", "wall", "hole"):
        assert np.array_equal(getattr(full, name), getattr(bare, name))
    assert (full.E > 0).any() and full.photons_used.sum() > 0
    assert not bare.E.any() and not bare.photons_used.any()
    assert len(no_zones.parts) == len(bare) and not any(len(z) for z in no_zones.parts)
