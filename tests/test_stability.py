"""Numerical stability of the whole bake: scale, offset, degenerate geometry, extreme inputs.

Scenes are built by hand (no bpy) and kept tiny (8x8..16x16 light maps, a few
thousand photons) so the file runs in seconds. The bench runs the large end
(4M photons, 2048^2 texels: ``bench/README.md``).
"""
import numpy as np
from scipy.spatial import cKDTree
import pytest

from pdic.core.hemisphere import Hemisphere
from pdic.core.interpolation import CacheLookup
from pdic.core.irradiance_cache import IrradianceCache, _clamped, neighbour_clamp
from pdic.core.vectors import norms
from pdic.core.photons import trace_photons
from pdic.core.pipeline import bake
from pdic.core.rays import RayCaster
from pdic.core.scene import BakeTarget, PointLight, Scene
from pdic.core.settings import preset
from pdic.core.ward import accepted, record_estimate, ward_weight

from scenes import UV_QUAD, box_faces, quad, quad_scene

_box_faces = box_faces


def _scene(faces_world, target_faces, light_world, power, albedo=0.8, res=12, extra=None) -> Scene:
    """Quads in world space, ``target_faces`` {name: quad index}, one point lamp (tests/scenes.py)."""
    lamp = PointLight("lamp", np.asarray(light_world, float), np.full(3, float(power)))
    return quad_scene(faces_world, {name: (face, res) for name, face in target_faces.items()}, [lamp],
                      albedo=albedo, extra=extra)


def _box(scale=1.0, offset=0.0, power=100.0, **kw) -> Scene:
    faces = [f * scale + offset for f in _box_faces()]
    return _scene(faces, {"floor": 0, "back": 1}, np.array([0.5, 0.5, 0.8]) * scale + offset, power, **kw)


def _maps(result) -> np.ndarray:
    return np.concatenate([result.lightmaps[n][..., :3].ravel() for n in sorted(result.lightmaps)])


def _all_finite(result) -> bool:
    parts = [_maps(result)] + [v.ravel() for v in result.indirect.values()]
    if result.cache is not None and len(result.cache):
        parts += [result.cache.E.ravel(), result.cache.R, result.cache.grad_r.ravel(), result.cache.grad_t.ravel()]
    return all(np.isfinite(p).all() for p in parts)


# --------------------------------------------------------------------------- scale and offset
@pytest.mark.parametrize("quality", ["PREVIEW", "FINAL"])
@pytest.mark.parametrize("scale, offset", [(1e-3, 0.0), (1e4, 0.0), (1.0, 1e5), (1e-3, 1e5)])
def test_light_maps_do_not_depend_on_scale_or_distance_from_origin(quality, scale, offset):
    # Power scales with the area so irradiance (and every light-map value) stays the same.
    settings = preset(quality, photons=4000, max_bounces=3, threads=1, hemisphere_theta=8, hemisphere_phi=16)
    reference = _maps(bake(_box(res=8), settings))
    moved = _maps(bake(_box(scale, offset, 100.0 * scale * scale, res=8), settings))
    assert np.isfinite(moved).all()
    assert np.abs(moved - reference).max() <= 0.01 * reference.mean()


def test_stored_photons_lie_on_the_surface_they_hit():
    # A bounce's hit distance is measured from its origin pushed epsilon off the surface; adding it
    # to the unpushed origin used to store photons up to epsilon (1e-5 of the diagonal) off their plane.
    scene = _box()
    caster = RayCaster(scene.geometry.positions, scene.extent)
    pm, _ = trace_photons(scene, caster, 5000, 3, seed=1)
    corner = scene.geometry.positions[pm.triangle, 0]
    off_plane = np.einsum("ij,ij->i", pm.p - corner, scene.geometry.face_normals()[pm.triangle])
    assert (pm.bounce > 0).any()
    assert np.abs(off_plane).max() < 0.02 * caster.epsilon


# --------------------------------------------------------------------------- degenerate geometry
def test_degenerate_and_sliver_triangles_bake_finite():
    p = np.array([0.3, 0.3, 0.0])
    degenerate = [[p, p, p],                                          # a point
                  [p, p + [0.2, 0, 0], p + [0.4, 0, 0]],              # collinear
                  [p + [0, 0, 0.5], p + [0.4, 0, 0.5], p + [0.2, 1e-9, 0.5]]]  # sliver, 1e-9 high
    faces = _box_faces()
    scene = _scene(faces, {"floor": 0, "back": 1}, [0.5, 0.5, 0.8], 100.0, extra=degenerate)
    # Bake the degenerate triangles too: a target made only of them and the floor.
    T = scene.geometry.count
    mixed = BakeTarget("mixed", np.array([0, 1, T - 3, T - 2, T - 1]),
                       np.concatenate([UV_QUAD, np.array([[[0.1, 0.1]] * 3, [[0.2, 0.2], [0.5, 0.2], [0.8, 0.2]],
                                                          [[0.1, 0.9], [0.9, 0.9], [0.5, 0.9 + 1e-7]]], np.float32)]),
                       12, 12)
    scene = Scene(scene.geometry, scene.materials, lights=scene.lights, targets=scene.targets + (mixed,),
                  origin_world=scene.origin_world)
    for quality in ("PREVIEW", "FINAL"):
        result = bake(scene, preset(quality, photons=3000, max_bounces=3, threads=1, hemisphere_theta=6,
                                    hemisphere_phi=12))
        assert _all_finite(result)
        assert _maps(result).max() > 0


def test_coincident_coplanar_faces_bake_finite_and_light_both():
    # Two floors in the same plane (z-fighting): both get direct light like one floor would.
    faces = _box_faces() + [quad([0, 0, 0], [1, 0, 0], [0, 1, 0])]
    scene = _scene(faces, {"floor": 0, "twin": 6}, [0.5, 0.5, 0.8], 100.0)
    result = bake(scene, preset("PREVIEW", photons=4000, max_bounces=3, threads=1))
    assert _all_finite(result)
    floor, twin = result.direct["floor"], result.direct["twin"]
    assert np.abs(floor - twin).max() <= 1e-6 * floor.max()
    assert result.indirect["twin"].mean() > 0


def _two_rooms(thickness: float):
    """Two 1 m rooms side by side, split by a wall ``thickness`` thick; the lamp is in the left one."""
    h = thickness / 2
    x0, x1 = 1.0 - h, 1.0 + h
    faces = [
        quad([0, 0, 0], [x0, 0, 0], [0, 1, 0]),            # 0 left floor (+z)
        quad([x1, 0, 0], [2 - x1, 0, 0], [0, 1, 0]),       # 1 right floor (+z)
        quad([0, 0, 1], [0, 1, 0], [2, 0, 0]),             # ceiling (-z)
        quad([0, 0, 0], [0, 0, 1], [2, 0, 0]),             # front (+y)
        quad([0, 1, 0], [2, 0, 0], [0, 0, 1]),             # back (-y)
        quad([0, 0, 0], [0, 1, 0], [0, 0, 1]),             # left end (+x)
        quad([2, 0, 0], [0, 0, 1], [0, 1, 0]),             # right end (-x)
        quad([x0, 0, 0], [0, 0, 1], [0, 1, 0]),            # 7 wall, left face (-x)
        quad([x1, 0, 0], [0, 1, 0], [0, 0, 1]),            # 8 wall, right face (+x)
        quad([x0, 0, 1], [0, 1, 0], [x1 - x0, 0, 0]),      # wall top, against the ceiling (-z)
    ]
    return _scene(faces, {"left": 0, "right": 1, "wall_right": 8}, [0.5, 0.5, 0.7], 100.0, res=16)


def _bake_two_rooms(quality):
    return bake(_two_rooms(1e-3), preset(quality, photons=20_000, max_bounces=4, threads=1,
                                         hemisphere_theta=8, hemisphere_phi=16))


@pytest.mark.parametrize("quality", ["PREVIEW", "FINAL"])
def test_no_direct_light_passes_a_1_mm_wall(quality):
    result = _bake_two_rooms(quality)
    assert _all_finite(result)
    assert result.indirect["left"].mean() > 0.05 * result.lightmaps["left"][..., :3].mean()
    for dark in ("right", "wall_right"):
        assert result.direct[dark].max() == 0.0


# Thin walls: records find the walls in their tangent plane (irradiance_cache.wall_distances) and are
# not used past them; gathering reads indirect light from those records, not from the nearest photon.
@pytest.mark.parametrize("quality", ["PREVIEW", "FINAL"])
def test_no_indirect_light_leaks_through_a_1_mm_wall(quality):
    result = _bake_two_rooms(quality)
    lit = result.lightmaps["left"][..., :3].mean()
    for dark in ("right", "wall_right"):
        # negligible: below 0.1 % of the lit room's mean texel
        assert result.indirect[dark].mean() <= 1e-3 * lit, (dark, result.indirect[dark].max(), lit)


# --------------------------------------------------------------------------- extreme inputs
@pytest.mark.parametrize("power", [1e-6, 1e9])
def test_light_maps_scale_linearly_with_power_from_1e_6_to_1e9(power):
    settings = preset("PREVIEW", photons=3000, max_bounces=3, threads=1)
    reference = _maps(bake(_box(res=8), settings))
    scaled = _maps(bake(_box(power=100.0 * power, res=8), settings))
    assert np.isfinite(scaled).all()
    np.testing.assert_allclose(scaled / power, reference, rtol=1e-4, atol=1e-6 * reference.max())


@pytest.mark.parametrize("quality", ["PREVIEW", "FINAL"])
def test_albedo_0_gives_no_indirect_light_and_albedo_1_stays_finite(quality):
    settings = preset(quality, photons=3000, max_bounces=4, threads=1, hemisphere_theta=6, hemisphere_phi=12)
    black = bake(_box(albedo=0.0, res=8), settings)
    assert _all_finite(black)
    assert all(v.max() == 0.0 for v in black.indirect.values())
    assert _maps(black).max() > 0  # direct light is still there
    white = bake(_box(albedo=1.0, res=8), settings)
    assert _all_finite(white)
    grey = bake(_box(albedo=0.5, res=8), settings)
    assert np.mean([v.mean() for v in white.indirect.values()]) > np.mean([v.mean() for v in grey.indirect.values()])


@pytest.mark.parametrize("photons", [1, 10, 1000])
@pytest.mark.parametrize("quality", ["PREVIEW", "FINAL"])
def test_any_photon_count_bakes_finite(photons, quality):
    # 4M photons run in the bench (bench/run.py, scaling and Sponza).
    result = bake(_box(res=8), preset(quality, photons=photons, max_bounces=3, threads=1,
                                      hemisphere_theta=6, hemisphere_phi=12))
    assert _all_finite(result)
    assert result.stats["counters"]["photons_emitted"] == photons


# --------------------------------------------------------------------------- randomised kernels
def _random_unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_randomised_ward_weights_are_finite_positive_and_accept_only_within_the_zone():
    rng = np.random.default_rng(11)
    for _ in range(50):
        m = 500
        scale = 10 ** rng.uniform(-6, 6)
        p_k = rng.normal(size=(m, 3)) * scale
        n_k = _random_unit(rng, m)
        p = p_k + rng.normal(size=(m, 3)) * scale * 10 ** rng.uniform(-9, 0, size=(m, 1))
        n = np.where(rng.random((m, 1)) < 0.3, n_k, _random_unit(rng, m))
        R = scale * 10 ** rng.uniform(-4, 1, size=m)
        a = rng.uniform(0.1, 1.0)
        w = ward_weight(p, n, p_k, n_k, R)
        assert np.isfinite(w).all() and (w > 0).all()
        ok = accepted(w, a, p, n, p_k, n_k, R)
        assert (np.linalg.norm(p[ok] - p_k[ok], axis=1) < a * R[ok] * (1 + 1e-12)).all()


def test_randomised_gradient_extrapolation_is_finite_and_exact_at_the_record():
    rng = np.random.default_rng(12)
    m = 2000
    E = rng.uniform(0, 1e6, size=(m, 3))
    g_r, g_t = rng.normal(size=(m, 3, 3)) * 1e6, rng.normal(size=(m, 3, 3)) * 1e6
    p_k, n_k = rng.normal(size=(m, 3)), _random_unit(rng, m)
    at_record = record_estimate(E, p_k, n_k, p_k, n_k, g_r, g_t)
    np.testing.assert_allclose(at_record, E, rtol=1e-12)
    moved = record_estimate(E, p_k + rng.normal(size=(m, 3)), _random_unit(rng, m), p_k, n_k, g_r, g_t)
    assert np.isfinite(moved).all()


def test_randomised_interpolation_with_gradients_never_negative_or_nan():
    rng = np.random.default_rng(13)
    for _ in range(10):
        K = int(rng.integers(1, 300))
        scale = 10 ** rng.uniform(-5, 5)
        cache = IrradianceCache(
            p=rng.normal(size=(K, 3)) * scale, n=_random_unit(rng, K), E=rng.uniform(0, 10, (K, 3)),
            R=scale * 10 ** rng.uniform(-2, 0, K), grad_r=rng.normal(size=(K, 3, 3)) * 10,
            grad_t=rng.normal(size=(K, 3, 3)) * 10 / scale, photons_used=np.zeros(K, np.int32),
            hole=np.zeros(K, bool), refined=np.ones(K, bool))
        q = cache.p + rng.normal(size=(K, 3)) * cache.R[:, None] * 0.2
        E, w = CacheLookup(cache, 0.5, True).irradiance(q, cache.n)
        assert np.isfinite(E).all() and np.isfinite(w).all() and (E >= 0).all()


def test_randomised_neighbour_clamp_is_1_lipschitz_and_never_grows():
    rng = np.random.default_rng(14)
    for _ in range(20):
        K = int(rng.integers(2, 400))
        scale = 10 ** rng.uniform(-4, 4)
        p = rng.uniform(0, 1, (K, 3)) * scale
        R = scale * 10 ** rng.uniform(-3, 0, K)
        out = neighbour_clamp(p, R)
        d = np.linalg.norm(p[:, None] - p[None], axis=2)
        assert (out <= R).all() and (out > 0).all()
        assert (out[:, None] <= out[None, :] + d + 1e-9 * scale).all()


def test_clamp_by_nearest_records_equals_the_brute_force_minimum():
    """_clamped asks the nearest records first and the ball query only where they cannot settle a
    point; its result is the brute-force min(R, min_j R_j + |p - p_j|) over every record, bit for bit."""
    rng = np.random.default_rng(16)
    for trial in range(12):
        n, B = int(rng.integers(1, 3000)), int(rng.integers(1, 400))
        flat = [1.0, 1.0, 1e-3 if trial % 2 else 1.0]  # records on a plane, or in a volume
        p_j, p = rng.random((n, 3)) * flat, rng.random((B, 3)) * flat
        R_j, R = 10 ** rng.uniform(-3, 0, n), 10 ** rng.uniform(-3, 0.3, B)
        if trial % 3 == 0:  # large zones and a few tiny ones: the nearest records cannot settle most points
            R_j = np.where(rng.random(n) < 0.01, 1e-3, rng.uniform(0.5, 1.0, n))
        brute = np.minimum(R, (R_j[None] + norms(p_j[None] - p[:, None])).min(axis=1))
        assert np.array_equal(_clamped(cKDTree(p_j), p_j, R_j, p, R, 1), brute)


def test_randomised_hemisphere_gathers_are_finite_for_extreme_radiance_and_distance():
    rng = np.random.default_rng(15)
    H = Hemisphere(8, 16)
    B = 64
    L = rng.uniform(0, 1, (B, H.cells, 3)) * 10 ** rng.uniform(-6, 9, (B, 1, 1))
    r = 10 ** rng.uniform(-8, 8, (B, H.cells))
    r[0, :5] = 0.0  # a hit at the record itself
    r[1] = np.inf  # nothing hit: open sky
    E, g_r, g_t = H.irradiance_and_gradients(L, r, rng.normal(size=(B, H.cells, 3)))
    for x in (E, g_r, g_t):
        assert np.isfinite(x).all()
    assert (E >= 0).all()
