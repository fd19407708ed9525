"""Direct irradiance (and texture albedo) against closed forms and numbers measured from Cycles 5.0 bakes.

Scenes are built by hand: a floor quad in z = 0 (normal +z) carries the
receiving points; lights and occluders are placed above it.
"""

import numpy as np
import pytest

from pdic.core import scene as sc
from pdic.core.albedo import albedo, sample_texture
from pdic.core.direct import EMISSIVE_KEY, DirectResult, direct_irradiance
from pdic.core.rays import RayCaster


def quad(centre, half_u, half_v, u=(1.0, 0.0, 0.0), v=(0.0, 1.0, 0.0)):
    """Two triangles of a rectangle, wound so the normal is u x v."""
    c, u, v = np.asarray(centre, float), np.asarray(u, float) * half_u, np.asarray(v, float) * half_v
    a, b, cc, d = c - u - v, c + u - v, c + u + v, c - u + v
    return [[a, b, cc], [a, cc, d]]


def make_scene(tris, lights=(), world=None, emission=None, material=None):
    """Scene of triangles (k, 3, 3); ``emission`` (M, 3) per material, ``material`` per triangle."""
    tris = np.asarray(tris, float)
    T = len(tris)
    fn = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True).clip(1e-300)
    emission = np.zeros((1, 3)) if emission is None else np.asarray(emission, float)
    M = len(emission)
    geometry = sc.Geometry(
        positions=tris,
        normals=np.repeat(fn[:, None, :], 3, axis=1),
        uvs=np.zeros((T, 3, 2)),
        material=np.zeros(T, int) if material is None else material,
        target=np.zeros(T, int),
    )
    materials = sc.Materials(tuple(f"m{i}" for i in range(M)), np.full((M, 3), 0.8), np.full(M, -1), emission)
    return sc.Scene(geometry, materials, lights=lights, world=world or sc.World())


def floor_points(n=9, half=0.9, z=0.0):
    x = np.linspace(-half, half, n)
    X, Y = np.meshgrid(x, x)
    p = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, z)])
    up = np.tile([0.0, 0.0, 1.0], (len(p), 1))
    return p, up


FLOOR = quad((0, 0, 0), 1.0, 1.0)


def run(scene, p, n, samples=16, seed=0, n_geo=None):
    caster = RayCaster(scene.geometry.positions, scene.extent)
    return direct_irradiance(scene, caster, p, n, n if n_geo is None else n_geo, samples, np.random.default_rng(seed))


def point_E(p, light_pos, P):
    delta = np.asarray(light_pos) - p
    d = np.linalg.norm(delta, axis=1)
    return P / (4 * np.pi * d ** 2) * np.clip(delta[:, 2] / d, 0, None)


def area_quadrature(p, centre, su, sv, L, ellipse=False, k=400):
    """Irradiance at points p (normal +z) below a downward-facing planar emitter in z = centre[2]."""
    g = ((np.arange(k) + 0.5) / k - 0.5)
    U, V = np.meshgrid(g * su, g * sv)
    inside = ((U / (su / 2)) ** 2 + (V / (sv / 2)) ** 2 <= 1) if ellipse else np.ones_like(U, bool)
    q = np.column_stack([centre[0] + U[inside], centre[1] + V[inside], np.full(inside.sum(), centre[2])])
    dA = su * sv / k / k
    out = []
    for x in p:
        w = q - x
        d2 = np.sum(w * w, axis=1)
        cos = w[:, 2] / np.sqrt(d2)
        out.append(L * np.sum(cos * cos / d2) * dA)
    return np.array(out)


# --------------------------------------------------------------------------- point
def test_point_light_irradiance_matches_inverse_square_cosine():
    light = sc.PointLight("lamp", np.array([0.3, -0.2, 1.0]), np.array([100.0, 50.0, 25.0]))
    s = make_scene(FLOOR, [light])
    p, n = floor_points()
    r = run(s, p, n)
    expected = point_E(p, light.position, 1.0)[:, None] * light.power
    assert np.allclose(r.E, expected, rtol=1e-9)
    assert r.shadow_rays["point"] == len(p) and r.skipped["lamp"] == 0


def test_occluder_blocks_point_light():
    light = sc.PointLight("lamp", np.array([0.0, 0.0, 2.0]), np.full(3, 100.0))
    blocker = quad((0.0, 0.0, 1.0), 0.2, 0.2)  # shadow on the floor: |x|, |y| < 0.4
    s = make_scene(FLOOR + blocker, [light])
    p, n = floor_points(n=11, half=0.8)
    r = run(s, p, n)
    shadowed = (np.abs(p[:, 0]) < 0.4) & (np.abs(p[:, 1]) < 0.4)
    assert shadowed.sum() == 25 and (~shadowed).sum() == 96
    assert np.all(r.E[shadowed] == 0.0)
    assert np.allclose(r.E[~shadowed, 0], point_E(p[~shadowed], light.position, 100.0), rtol=1e-9)


def test_a_point_lights_edge_evidence_is_its_lit_and_its_unoccluded_light():
    """An exact light's one ray is each point's lit share: the edge evidence (deviation direct-footprint) holds
    its light as E does, and unblocked, with no ray of its own."""
    light = sc.PointLight("lamp", np.array([0.0, 0.0, 2.0]), np.full(3, 100.0))
    s = make_scene(FLOOR + quad((0.0, 0.0, 1.0), 0.2, 0.2), [light])
    p, n = floor_points(n=11, half=0.8)
    caster = RayCaster(s.geometry.positions, s.extent)
    plain = direct_irradiance(s, caster, p, n, n, 4, np.random.default_rng(0))
    r = direct_irradiance(s, caster, p, n, n, 4, np.random.default_rng(0), edge_rng=np.random.default_rng(1))
    assert np.array_equal(r.E, plain.E) and np.array_equal(r.edge_lit, r.E)
    np.testing.assert_allclose(r.edge_open[:, 0], point_E(p, light.position, 100.0), rtol=1e-9)
    assert r.shadow_rays["point"] == plain.shadow_rays["point"] == 121  # one ray a lit point, none for the evidence


def test_points_facing_away_receive_nothing_and_cast_no_shadow_rays():
    lights = [sc.PointLight("lamp", np.array([0.0, 0.0, 1.0]), np.full(3, 100.0)),
              sc.PointLight("soft", np.array([0.0, 0.0, 1.0]), np.full(3, 100.0), radius=0.2),
              sc.SpotLight("spot", np.array([0.0, 0.0, 1.0]), np.array([0, 0, -1.0]), np.full(3, 100.0), 0.5, 0.2),
              sc.SunLight("sun", np.array([0.0, 0.0, 1.0]), np.full(3, 3.0), np.radians(5)),
              sc.AreaLight("area", np.array([0.0, 0.0, 1.0]), np.array([0, 0, -1.0]), np.array([1.0, 0, 0]),
                           np.array([0, 1.0, 0]), 0.5, 0.5, "SQUARE", np.full(3, 10.0))]
    s = make_scene(FLOOR, lights)
    p, n = floor_points()
    r = run(s, p, -n)  # normals point down, away from every light
    assert np.all(r.E == 0.0)
    assert sum(r.shadow_rays.values()) == 0
    assert all(r.skipped[light.name] == len(p) for light in lights)


def test_shading_normal_weights_cosine_but_geometric_normal_rejects_light_from_below():
    light = sc.PointLight("lamp", np.array([0.0, 0.0, 1.0]), np.full(3, 100.0))
    s = make_scene(FLOOR, [light])
    p = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    tilt = np.array([np.sin(0.5), 0.0, np.cos(0.5)])
    n_s = np.array(tilt[None].repeat(2, 0))
    n_g = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])  # second point: light is below its face
    r = run(s, p, n_s, n_geo=n_g)
    assert r.E[0, 0] == pytest.approx(100 / (4 * np.pi) * np.cos(0.5), rel=1e-9)
    assert r.E[1, 0] == 0.0 and r.shadow_rays["point"] == 1


def test_soft_point_light_matches_cycles_soft_falloff_disk():
    # Cycles 5.0 bake, point P=100 W radius 0.3 at (0.3, -0.2, 0.5), default soft falloff:
    # texel at (0.3125, -0.1875, 0) measured E = 23.297 (hard point would give 31.77).
    light = sc.PointLight("soft", np.array([0.3, -0.2, 0.5]), np.full(3, 100.0), radius=0.3)
    s = make_scene(FLOOR, [light])
    p = np.array([[0.3125, -0.1875, 0.0]])
    r = run(s, p, np.array([[0, 0, 1.0]]), samples=4096)
    assert r.E[0, 0] == pytest.approx(23.297, rel=0.01)
    assert r.shadow_rays["point"] == 4096


def test_soft_point_light_far_away_tends_to_point_light():
    light = sc.PointLight("soft", np.array([0.1, 0.0, 20.0]), np.full(3, 100.0), radius=0.05)
    s = make_scene(FLOOR, [light])
    p, n = floor_points(n=3)
    r = run(s, p, n, samples=16)
    assert np.allclose(r.E[:, 0], point_E(p, light.position, 100.0), rtol=1e-4)


def SphereLight(name, position, power, radius):  # noqa: N802 (reads like the light it builds)
    """A point light with Blender's ``use_soft_falloff`` off: a uniform sphere."""
    return sc.PointLight(name, position, power, radius=radius, soft_falloff=False)


def test_sphere_light_above_horizon_equals_point_light():
    # A fully visible uniform sphere gives exactly P cos / (4 pi D^2).
    light = SphereLight("sphere", np.array([0.3, -0.2, 0.8]), np.full(3, 100.0), radius=0.3)
    s = make_scene(FLOOR, [light])
    p, n = floor_points(n=3, half=0.3)
    r = run(s, p, n, samples=1024)
    assert np.allclose(r.E[:, 0], point_E(p, light.position, 100.0), rtol=0.01)


# --------------------------------------------------------------------------- spot
def test_spot_light_inside_outside_and_blend_match_cycles():
    # Cycles 5.0: spot P=100 at (0,0,1) pointing down, spot_size 60 deg (half 30), blend 1;
    # attenuation measured at the texel angles below (bake of a 2x2 plane, 64x64 texels).
    measured = {1.27: 0.9998, 11.52: 0.9390, 16.56: 0.7722, 21.35: 0.4815, 25.86: 0.1599, 33.90: 0.0}
    ang = np.radians(np.array(list(measured)))
    p = np.column_stack([np.tan(ang), np.zeros_like(ang), np.zeros_like(ang)])
    n = np.tile([0, 0, 1.0], (len(p), 1))
    point = point_E(p, (0, 0, 1.0), 100.0)
    for blend, expect in ((1.0, np.array(list(measured.values()))),
                          (0.15, np.array([1, 1, 1, 1, 1, 0.0])),
                          (0.0, np.array([1, 1, 1, 1, 1, 0.0]))):
        spot = sc.SpotLight("spot", np.array([0, 0, 1.0]), np.array([0, 0, -1.0]), np.full(3, 100.0), np.radians(30), blend)
        r = run(make_scene(FLOOR, [spot]), p, n)
        assert np.allclose(r.E[:, 0] / point, expect, atol=2e-3), blend
        assert r.shadow_rays["spot"] == 5 and r.skipped["spot"] == 1  # outside the cone: no ray


def test_spot_blend_region_follows_smoothstep():
    half, blend = np.radians(30), 0.15
    cos_h = np.cos(half)
    cos_a = cos_h + (1 - cos_h) * blend * np.array([0.25, 0.5, 0.75])
    ang = np.arccos(cos_a)
    p = np.column_stack([np.tan(ang), np.zeros(3), np.zeros(3)])
    spot = sc.SpotLight("spot", np.array([0, 0, 1.0]), np.array([0, 0, -1.0]), np.full(3, 100.0), half, blend)
    r = run(make_scene(FLOOR, [spot]), p, np.tile([0, 0, 1.0], (3, 1)))
    x = np.array([0.25, 0.5, 0.75])
    assert np.allclose(r.E[:, 0] / point_E(p, (0, 0, 1.0), 100.0), 3 * x * x - 2 * x ** 3, rtol=1e-9)


# --------------------------------------------------------------------------- sun
def test_sun_irradiance_is_strength_times_cosine():
    theta = np.radians(40)
    direction = np.array([0.0, np.sin(theta), np.cos(theta)])
    p, n = floor_points()
    for half_angle, rel in ((0.0, 1e-12), (np.radians(10.0), 0.03)):
        sun = sc.SunLight("sun", direction, np.array([3.0, 2.0, 1.0]), half_angle)
        r = run(make_scene(FLOOR, [sun]), p, n, samples=16)
        assert np.allclose(r.E, np.cos(theta) * sun.irradiance, rtol=rel)
        assert np.allclose(r.E.mean(0), np.cos(theta) * sun.irradiance, rtol=min(rel, 2e-3))
        assert r.shadow_rays["sun"] == len(p) * (1 if half_angle == 0 else 16)


# --------------------------------------------------------------------------- world
def test_unoccluded_world_gives_pi_L():
    world = sc.World(np.array([0.7, 0.5, 0.1]))
    p, n = floor_points(n=4)
    r = run(make_scene(FLOOR, world=world), p, n)
    assert np.allclose(r.E, np.pi * world.radiance, rtol=1e-12)


def test_wall_blocks_analytic_cosine_weighted_fraction_of_world():
    # Infinitely wide wall of height H at distance a: form factor F = (1 - a / sqrt(a^2 + H^2)) / 2.
    a, H = 1.0, 1.0
    wall = quad((a, 0.0, H / 2), 50.0, H / 2, u=(0, 1.0, 0), v=(0, 0, 1.0))
    world = sc.World(np.full(3, 1.0))
    p = np.column_stack([np.zeros(200), np.linspace(-1, 1, 200), np.zeros(200)])
    n = np.tile([0, 0, 1.0], (200, 1))
    r = run(make_scene(FLOOR + wall, world=world), p, n, samples=256)
    F = (1 - a / np.hypot(a, H)) / 2
    assert r.E[:, 0].mean() / np.pi == pytest.approx(1 - F, abs=0.005)
    # A very tall wall hides half the sky.
    tall = quad((a, 0.0, 50.0), 50.0, 50.0, u=(0, 1.0, 0), v=(0, 0, 1.0))
    r = run(make_scene(FLOOR + tall, world=world), p, n, samples=64)
    assert r.E[:, 0].mean() / np.pi == pytest.approx(0.5 + 0.5 / np.hypot(1, 100), abs=0.01)


# --------------------------------------------------------------------------- area
def test_disk_area_light_on_axis_matches_closed_form():
    r_disk, d, L = 0.4, 0.8, 5.0
    light = sc.AreaLight("disk", np.array([0, 0, d]), np.array([0, 0, -1.0]), np.array([1.0, 0, 0]),
                         np.array([0, 1.0, 0]), 2 * r_disk, 2 * r_disk, "DISK", np.full(3, L))
    r = run(make_scene(FLOOR, [light]), np.zeros((1, 3)), np.array([[0, 0, 1.0]]), samples=4096)
    assert r.E[0, 0] == pytest.approx(np.pi * L * r_disk ** 2 / (r_disk ** 2 + d ** 2), rel=5e-3)


@pytest.mark.parametrize("shape,su,sv", [("SQUARE", 0.6, 0.6), ("RECTANGLE", 0.8, 0.3), ("DISK", 0.6, 0.6), ("ELLIPSE", 0.8, 0.4)])
def test_area_light_shapes_match_quadrature(shape, su, sv):
    centre = np.array([0.2, 0.1, 0.7])
    light = sc.AreaLight("a", centre, np.array([0, 0, -1.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]),
                         su, sv, shape, np.array([2.0, 1.0, 0.5]))
    p, n = floor_points(n=3, half=0.8)
    r = run(make_scene(FLOOR, [light]), p, n, samples=1024)
    expected = area_quadrature(p, centre, su, sv, 1.0, ellipse=shape in ("DISK", "ELLIPSE"))
    assert np.allclose(r.E, expected[:, None] * light.radiance, rtol=0.01)


def test_area_light_is_one_sided_and_skips_points_behind_it():
    light = sc.AreaLight("up", np.array([0, 0, 0.5]), np.array([0, 0, 1.0]), np.array([1.0, 0, 0]),
                         np.array([0, 1.0, 0]), 0.5, 0.5, "SQUARE", np.full(3, 10.0))
    p, n = floor_points(n=3)
    r = run(make_scene(FLOOR, [light]), p, n)
    assert np.all(r.E == 0) and r.shadow_rays["area"] == 0 and r.skipped["up"] == len(p)


# --------------------------------------------------------------------------- emissive triangles
@pytest.mark.parametrize("flip", [False, True])
def test_emissive_triangle_pair_equals_same_area_light_from_either_side(flip):
    L, centre, half = 5.0, np.array([0.2, 0.1, 0.7]), 0.3
    u, v = ((1.0, 0, 0), (0, -1.0, 0)) if not flip else ((1.0, 0, 0), (0, 1.0, 0))  # normal -z or +z
    emitter = quad(centre, half, half, u=u, v=v)
    s = make_scene(FLOOR + emitter, emission=[[0, 0, 0], [L, L / 2, 0]], material=np.array([0, 0, 1, 1]))
    p, n = floor_points(n=3, half=0.8)
    r = run(s, p, n, samples=1024)
    light = sc.AreaLight("a", centre, np.array([0, 0, -1.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]),
                         2 * half, 2 * half, "SQUARE", np.array([L, L / 2, 0]))
    r_area = run(make_scene(FLOOR, [light]), p, n, samples=1024)
    expected = area_quadrature(p, centre, 2 * half, 2 * half, 1.0)[:, None] * np.array([L, L / 2, 0])
    assert np.allclose(r.E, expected, rtol=0.01, atol=1e-12)
    assert np.allclose(r.E, r_area.E, rtol=0.015, atol=1e-12)
    assert r.shadow_rays["emissive"] > 0


def test_emitters_are_picked_by_power():
    # A bright and a dim emitter with equal solid angle: all samples go where the power is.
    bright = quad((-0.5, 0, 1.0), 0.1, 0.1, v=(0, -1.0, 0))
    dim = quad((0.5, 0, 1.0), 0.1, 0.1, v=(0, -1.0, 0))
    s = make_scene(FLOOR + bright + dim, emission=[[0, 0, 0], [100.0] * 3, [1.0] * 3], material=np.array([0, 0, 1, 1, 2, 2]))
    p = np.array([[0.0, 0.0, 0.0]])
    r = run(s, p, np.array([[0, 0, 1.0]]), samples=4096)
    expected = (area_quadrature(p, (-0.5, 0, 1.0), 0.2, 0.2, 100.0) + area_quadrature(p, (0.5, 0, 1.0), 0.2, 0.2, 1.0))
    assert r.E[0, 0] == pytest.approx(expected[0], rel=0.01)


# --------------------------------------------------------------------------- degenerate input
def test_degenerate_inputs_give_finite_irradiance():
    lights = [sc.PointLight("zero", np.array([0, 0, 1.0]), np.zeros(3)),
              sc.PointLight("on_point", np.array([0.0, 0.0, 0.0]), np.full(3, 10.0)),
              sc.PointLight("soft_on_point", np.array([0.0, 0.0, 0.0]), np.full(3, 10.0), radius=0.1),
              SphereLight("sphere_around_point", np.array([0.0, 0.0, 0.05]), np.full(3, 10.0), radius=0.1),
              sc.SpotLight("spot_on_point", np.array([0.0, 0.0, 0.0]), np.array([0, 0, -1.0]), np.full(3, 10.0), 0.0, 0.0),
              sc.SunLight("zero_dir", np.zeros(3), np.full(3, 1.0)),
              sc.AreaLight("flat", np.array([0, 0, 1.0]), np.array([0, 0, -1.0]), np.array([1.0, 0, 0]),
                           np.array([0, 1.0, 0]), 0.0, 0.5, "RECTANGLE", np.full(3, 10.0))]
    sliver = [[[0, 0, 1.0], [0.5, 0, 1.0], [1.0, 0, 1.0]]]  # zero-area emitter
    s = make_scene(FLOOR + sliver, lights, emission=[[0, 0, 0], [5.0] * 3], material=np.array([0, 0, 1]))
    p, n = floor_points(n=3)
    n[0] = 0.0  # a zero-length normal too
    r = run(s, p, n, n_geo=n)
    assert np.all(np.isfinite(r.E)) and r.E.min() >= 0
    assert r.skipped[EMISSIVE_KEY] == len(p) and r.shadow_rays["emissive"] == 0
    assert r.skipped["zero"] == len(p) and r.skipped["flat"] == len(p)
    with pytest.raises(sc.SceneError, match="blob"):
        run(make_scene(FLOOR, [sc.AreaLight("blob", np.zeros(3), np.array([0, 0, 1.0]), np.array([1.0, 0, 0]),
                                            np.array([0, 1.0, 0]), 1, 1, "STAR", np.ones(3))]), p, n)


def test_chunks_concatenate_to_the_whole():
    light = sc.PointLight("lamp", np.array([0.3, -0.2, 1.0]), np.full(3, 100.0))
    s = make_scene(FLOOR, [light])
    p, n = floor_points()
    whole = run(s, p, n)
    parts = DirectResult.concatenate([run(s, p[i:i + 10], n[i:i + 10]) for i in range(0, len(p), 10)])
    assert np.array_equal(parts.E, whole.E)
    assert parts.shadow_rays == whole.shadow_rays and parts.skipped == whole.skipped


def test_soft_spot_light_masks_each_sample_as_cycles():
    # Cycles 5.0: spot P=100, radius 0.3 (soft falloff), at (0,0,1) down, 60 deg, blend 1;
    # 16x16 bake of the 2x2 floor, texels at y = 0.0625 and x = 0.0625, 0.3125, 0.5625.
    spot = sc.SpotLight("spot", np.array([0, 0, 1.0]), np.array([0, 0, -1.0]), np.full(3, 100.0), np.radians(30), 1.0, 0.3)
    p = np.array([[0.0625, 0.0625, 0], [0.3125, 0.0625, 0], [0.5625, 0.0625, 0]])
    r = run(make_scene(FLOOR, [spot]), p, np.tile([0, 0, 1.0], (3, 1)), samples=2048)
    assert np.allclose(r.E[:, 0], [6.352, 3.484, 0.804], rtol=0.03)  # texel averaging on the slope


def test_area_light_flush_with_a_ceiling_is_not_shadowed_by_it():
    h = 0.7
    ceiling = quad((0, 0, h), 1.0, 1.0, v=(0, -1.0, 0))
    light = sc.AreaLight("a", np.array([0.2, 0.1, h]), np.array([0, 0, -1.0]), np.array([1.0, 0, 0]),
                         np.array([0, 1.0, 0]), 0.6, 0.6, "SQUARE", np.ones(3))
    p, n = floor_points(n=3, half=0.8)
    r = run(make_scene(FLOOR + ceiling, [light]), p, n, samples=1024)
    assert np.allclose(r.E[:, 0], area_quadrature(p, (0.2, 0.1, h), 0.6, 0.6, 1.0), rtol=0.01)


# --------------------------------------------------------------------------- albedo
# 2x2 texture, row 0 = bottom (v < 0.5): bottom-left red, bottom-right green, top-left blue, top-right white.
PIX = np.array([[[1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 1, 1]]], np.float32)


def test_closest_texture_lookup_uses_bottom_row_first_and_repeats():
    tex = sc.Texture("t", PIX, "Closest")
    uv = np.array([[0.25, 0.25], [0.75, 0.25], [0.25, 0.75], [0.75, 0.75], [1.25, -0.75], [-0.25, 2.25]])
    got = sample_texture(tex, uv)
    assert np.array_equal(got, [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1], [1, 0, 0], [0, 1, 0]])


def test_linear_texture_lookup_is_bilinear_between_pixel_centres_with_wrap():
    tex = sc.Texture("t", PIX, "Linear")
    uv = np.array([[0.25, 0.25], [0.5, 0.25], [0.5, 0.5], [0.0, 0.25], [0.375, 0.25]])
    got = sample_texture(tex, uv)
    expected = [[1, 0, 0], [0.5, 0.5, 0], [0.5, 0.5, 0.5], [0.5, 0.5, 0], [0.75, 0.25, 0]]
    assert np.allclose(got, expected, atol=1e-6)


def test_albedo_interpolates_texture_uv_and_returns_constant_colours():
    tris = np.array(FLOOR, float)
    uvs = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
    geometry = sc.Geometry(tris, np.tile([0, 0, 1.0], (2, 3, 1)), uvs, np.array([0, 1]), np.zeros(2))
    materials = sc.Materials(("plain", "textured"), np.array([[0.2, 0.4, 0.6], [0.9, 0.9, 0.9]]),
                             np.array([-1, 0]), np.zeros((2, 3)))
    s = sc.Scene(geometry, materials, textures=(sc.Texture("t", PIX, "Closest"),))
    # Triangle 1, barycentric (u, v) = (0.1, 0.8): uv = 0.1 (1,1) + 0.8 (0,1) = (0.1, 0.9) -> top-left blue.
    got = albedo(s, np.array([0, 1, 1]), np.array([[0.3, 0.3], [0.1, 0.8], [0.8, 0.1]]))
    assert got.dtype == np.float32
    assert np.allclose(got, [[0.2, 0.4, 0.6], [0, 0, 1], [1, 1, 1]])


def test_point_lights_of_radius_0_cast_the_rays_their_samples_would(monkeypatch):
    """A hard point light takes a short path (its rays straight from point_light_rays, compiled or numpy):
    the same E, rays and skipped points to the bit as the general path through its (k, 1) samples."""
    from pdic.core import native_kernels
    from pdic.core.lights import point_light_rays_numpy

    rng = np.random.default_rng(4)
    blocker = quad((0.1, 0.0, 0.6), 0.3, 0.2)
    lights = [sc.PointLight("lamp", np.array([0.0, 0.0, 1.0]), np.array([100.0, 50.0, 25.0])),
              sc.PointLight("low", np.array([0.3, -0.2, 0.05]), np.full(3, 40.0)),
              sc.PointLight("dark", np.array([0.0, 0.0, 2.0]), np.zeros(3))]
    s = make_scene(FLOOR + blocker, lights)
    p, n = floor_points(n=41, half=0.95)
    n_s = n + rng.normal(scale=0.3, size=n.shape)  # bent shading normals: some see a light the face does not
    p[7] = lights[1].position  # a point at a light receives nothing from it
    caster = RayCaster(s.geometry.positions, s.extent)
    library = native_kernels.library
    monkeypatch.setattr(sc.PointLight, "hard", False)
    runs = {"general": direct_irradiance(s, caster, p, n_s, n, 1, np.random.default_rng(0))}
    monkeypatch.undo()
    assert lights[0].hard and not sc.PointLight("soft", np.zeros(3), np.ones(3), radius=0.1).hard
    monkeypatch.setattr(native_kernels, "library", lambda: None)
    runs["numpy"] = direct_irradiance(s, caster, p, n_s, n, 1, np.random.default_rng(0))
    monkeypatch.setattr(native_kernels, "library", library)
    runs["compiled"] = direct_irradiance(s, caster, p, n_s, n, 1, np.random.default_rng(0))
    for path in ("numpy", "compiled"):
        assert np.array_equal(runs[path].E, runs["general"].E), path
        assert runs[path].shadow_rays == runs["general"].shadow_rays and runs[path].skipped == runs["general"].skipped
    assert 0 < (runs["general"].E[:, 0] == 0).sum() < len(p) and runs["general"].skipped["dark"] == len(p)
    assert native_kernels.library() is not None
    # the kernel itself, against numpy, over many decades and at the light
    p = rng.normal(size=(20000, 3)) * 10.0 ** rng.uniform(-4, 3, (20000, 1))
    p[::101] = 0.0
    n_s, n_g = (v / np.linalg.norm(v, axis=1, keepdims=True) for v in rng.normal(size=(2, 20000, 3)))
    want = point_light_rays_numpy(p, n_s, n_g, np.zeros(3), 1e-4)
    got = native_kernels.point_light_rays(native_kernels.library(), p, n_s, n_g, np.zeros(3), 1e-4)
    assert all(np.array_equal(x, y) for x, y in zip(want, got)) and len(want[0]) > 1000


def test_a_scene_makes_its_emitters_once_and_a_changed_or_pickled_copy_its_own():
    import pickle
    from dataclasses import replace

    from scenes import quad, quad_scene

    lamp = sc.PointLight("Lamp", np.array([0.0, 0.0, 1.0]), np.array([100.0, 100.0, 100.0]))
    emission = np.array([[0.0, 0.0, 0.0], [2.0, 2.0, 2.0]])
    floor, glow = quad([0, 0, 0], [1, 0, 0], [0, 1, 0]), quad([0, 0, 2], [1, 0, 0], [0, 1, 0])
    scene = quad_scene([floor, glow], {}, [lamp], emission=emission, materials=np.array([0, 0, 1, 1], np.int32))
    emitters = scene.emitters()
    assert scene.emitters() is emitters  # every batch of shadow rays asks: made once
    assert [type(e).__name__ for e in emitters] == ["PointLight", "EmissiveMesh"]
    unlit = replace(scene, lights=())  # a new scene: its own emitters, not the first one's
    assert [type(e).__name__ for e in unlit.emitters()] == ["EmissiveMesh"]
    copy = pickle.loads(pickle.dumps(scene))  # a Dask worker's copy makes its own
    assert "_emitters" not in copy.__dict__ and [e.name for e in copy.emitters()][0] == "Lamp"
    assert len(copy.emitters()) == 2
