"""Direct light over texel footprints at hard shadow edges (core/direct_footprint.py, deviation direct-footprint).

A 1 m floor at z = 0 baked at 32^2, a 300 W point light (radius 0) 3 m above its centre and a
large occluder triangle at z = 1 whose edge casts a straight shadow edge across the floor at 30
degrees to the texel grid. Each texel's exact value is the lit part of its footprint (a square
clipped by the edge's half-plane) times E at that part's centroid (E varies by < 1 % across a texel
here), divided by pi. The footprint is the square of DIRECT_FOOTPRINT_SIDE = 0.5 texel centred on
the texel: what Cycles' bake integrates (checked here against a Cycles bake of the same plane).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pdic.core.constants import DIRECT_FOOTPRINT_SIDE
from pdic.core.pipeline import bake
from pdic.core.scene import PointLight
from pdic.core.settings import Deviations, preset

from scenes import quad, quad_scene

RES = 32
POWER = 300.0
LIGHT = np.array([0.5, 0.5, 3.0])
OCCLUDER_Z = 1.0
THETA = np.radians(30.0)
A = np.array([np.cos(THETA), np.sin(THETA)])  # the floor's shadow edge: A . q = EDGE_T, shadow below
EDGE_T = float(A @ [0.5, 0.5]) + 0.013
DIRECT = preset("FINAL", indirect=False, threads=1)


def _scene():
    """Floor target (index 0) and an occluder triangle covering the half-plane A . o < t_o at z = 1."""
    s = 1.0 - OCCLUDER_Z / LIGHT[2]  # the floor point q projects through the light to o = s q + (1 - s) L
    t_o = EDGE_T * s + (1.0 - s) * float(A @ LIGHT[:2])
    d = np.array([-A[1], A[0]])
    p0 = A * t_o
    corners = [p0 + 10 * d, p0 - 10 * d, p0 - 10 * A]
    occluder = np.array([[[c[0], c[1], OCCLUDER_Z] for c in corners]])
    floor = quad(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]))
    return quad_scene([floor], {"floor": (0, RES)}, [PointLight("lamp", LIGHT, np.full(3, POWER))],
                      extra=occluder)


def _clip(poly: np.ndarray, a: np.ndarray, t: float) -> np.ndarray:
    """The part of convex polygon (k, 2) where a . q >= t (Sutherland-Hodgman, one half-plane)."""
    out = []
    for p, q in zip(poly, np.roll(poly, -1, axis=0)):
        dp, dq = a @ p - t, a @ q - t
        if dp >= 0:
            out.append(p)
        if (dp >= 0) != (dq >= 0):
            out.append(p + dp / (dp - dq) * (q - p))
    return np.array(out).reshape(-1, 2)


def _area_centroid(poly: np.ndarray) -> tuple[float, np.ndarray]:
    if len(poly) < 3:
        return 0.0, np.zeros(2)
    x, y = poly[:, 0], poly[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = 0.5 * cross.sum()
    return abs(area), np.array([((x + xn) * cross).sum(), ((y + yn) * cross).sum()]) / (6 * area)


def exact_texels(side: float = DIRECT_FOOTPRINT_SIDE) -> tuple[np.ndarray, np.ndarray]:
    """(RES, RES) exact E / pi averaged over each texel's centred footprint of ``side`` texels, and
    (RES, RES) that footprint's lit fraction (rows = y). On the floor's diagonal, the edge between its two
    triangles through the texel centres, the footprint is the part on the triangle under Blender's scan
    point (y > x), as Cycles keeps its jitter there (docs/DEVIATIONS.md, crease-folding)."""
    value = np.zeros((RES, RES))
    fraction = np.zeros((RES, RES))
    h = 1.0 / RES
    q = 0.5 * side
    for j in range(RES):
        for i in range(RES):
            square = (np.array([[-q, -q], [q, -q], [q, q], [-q, q]]) + [i + 0.5, j + 0.5]) * h
            if i == j:
                square = _clip(square, np.array([-1.0, 1.0]), 0.0)
            area, c = _area_centroid(_clip(square, A, EDGE_T))
            fraction[j, i] = area / _area_centroid(square)[0]
            if area > 0:
                d = LIGHT - np.array([c[0], c[1], 0.0])
                r2 = d @ d
                value[j, i] = fraction[j, i] * POWER * (d[2] / np.sqrt(r2)) / (4 * np.pi * r2) / np.pi
    return value, fraction


@pytest.fixture(scope="module")
def exact():
    return exact_texels()


def _direct(settings):
    result = bake(_scene(), settings)
    return result.direct["floor"][..., 0].astype(np.float64), result.stats["counters"]


# (1, 0.5) and (2, 1.0): the footprint is wider than the samples' hull, edges found through the neighbour test
@pytest.mark.parametrize("texel_samples, side", [(1, 0.5), (2, 0.5), (4, 0.5), (2, 1.0)])
def test_hard_shadow_edge_texels_hold_their_lit_fraction(texel_samples, side):
    value, fraction = exact_texels(side)
    pdic, counters = _direct(replace(DIRECT, texel_samples=texel_samples, direct_footprint_side=side))
    full = value.max()
    err = np.abs(pdic - value) / full
    edge = (fraction > 0) & (fraction < 1)
    assert edge.sum() > 20
    assert err[edge].max() < 0.08, f"worst edge texel off by {err[edge].max():.3f} of a lit texel"
    assert np.sqrt((err[edge] ** 2).mean()) < 0.025
    assert err[~edge].max() < 0.01  # away from the edge the footprint changes nothing that matters
    # the extra points go to the edge only: a few texels either side of it, not the map (a texel the edge only
    # grazes, lit or shadowed over all but 1 % of its footprint, may keep its samples)
    clear = (fraction > 0.01) & (fraction < 0.99)
    assert clear.sum() <= counters["direct_footprint_texels"] < 0.2 * RES * RES
    assert counters["direct_footprint_shadow_rays"] > 0


def test_without_footprint_the_edge_aliases_and_no_footprint_ray_is_cast(exact):
    value, fraction = exact
    pdic, counters = _direct(replace(DIRECT, deviations=Deviations(direct_footprint=False)))
    edge = (fraction > 0) & (fraction < 1)
    err = np.abs(pdic - value) / value.max()
    assert err[edge].max() > 0.1  # the 2x2 points read the lit fraction in quarters
    assert "direct_footprint_shadow_rays" not in counters


def test_footprint_direct_light_is_the_same_for_the_same_seed_and_changes_with_it():
    a, _ = _direct(DIRECT)
    b, _ = _direct(DIRECT)
    c, _ = _direct(replace(DIRECT, seed=1))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_cycles_bake_integrates_the_footprint_the_addon_sets_for_this_blender(blender):
    """The footprint PDIC copies: Cycles' Diffuse Direct bake of the same plane holds the lit share of
    the centred square ``cycles_footprint_side`` gives for the running Blender (0.5 texel in 5.0-5.1,
    rms 0.5 % at 256 spp; the whole texel in 5.2), not of the other one (10.7 %)."""
    import cycles_reference as cr

    from pdic.pdic_addon.properties import cycles_footprint_side

    bpy = blender
    world = bpy.data.worlds.new("World")
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    bpy.context.scene.world = world
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=(0.5, 0.5, 0.0))  # its UVMap spans [0, 1]^2 like the quad's
    floor = bpy.context.object
    occluder = _scene().geometry.positions[2] + _scene().origin_world  # the occluder triangle, world space
    mesh = bpy.data.meshes.new("Occluder")
    mesh.from_pydata([tuple(v) for v in occluder], [], [(0, 1, 2)])
    bpy.context.scene.collection.objects.link(bpy.data.objects.new("Occluder", mesh))
    bpy.ops.object.light_add(type="POINT", location=tuple(LIGHT))
    bpy.context.object.data.energy, bpy.context.object.data.shadow_soft_size = POWER, 0.0
    C = cr.cycles_bake_full([floor], "UVMap", RES, RES, {"DIRECT"}, 256).images[floor.name][..., 0]
    side = cycles_footprint_side(bpy.app.version)
    whole, whole_fraction = exact_texels(1.0)
    edge = (whole_fraction > 0) & (whole_fraction < 1)

    def rms(expected):
        return np.sqrt((((C - expected) / whole.max())[edge] ** 2).mean())

    assert rms(exact_texels(side)[0]) < 0.015, (bpy.app.version, side)
    assert rms(exact_texels(1.5 - side)[0]) > 0.06, (bpy.app.version, side)  # the other footprint


def test_soft_shadow_keeps_its_mean_and_spends_the_regular_rays_on_penumbra_texels():
    """An area light's penumbra is refined with direct_samples x 4 / 64 = 1 ray per footprint point:
    the map's mean stays within noise and a refined texel costs what its 2 x 2 samples did."""
    from pdic.core.scene import AreaLight

    light = AreaLight("panel", LIGHT, np.array([0, 0, -1.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]),
                      0.6, 0.6, "SQUARE", np.full(3, 50.0))
    floor = quad(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]))
    scene = _scene()
    scene = quad_scene([floor], {"floor": (0, RES)}, [light], extra=scene.geometry.positions[2:] + scene.origin_world)
    on = bake(scene, DIRECT)
    off = bake(scene, replace(DIRECT, deviations=Deviations(direct_footprint=False)))
    a, b = on.direct["floor"], off.direct["floor"]
    counters = on.stats["counters"]
    refined = counters["direct_footprint_texels"]
    assert 0 < refined < RES * RES
    assert counters["direct_footprint_shadow_rays"] <= refined * 64  # one ray per point, not 16
    assert abs(a.mean() / b.mean() - 1.0) < 0.01
    assert np.isfinite(a).all()


def test_footprint_leaves_the_indirect_light_bit_identical():
    """Only the edge texels' direct values change: the cache, its lookups and the indirect map do not."""
    settings = preset("FINAL", photons=4000, max_bounces=3, threads=1, hemisphere_theta=6, hemisphere_phi=12)
    on = bake(_scene(), settings)
    off = bake(_scene(), replace(settings, deviations=Deviations(direct_footprint=False)))
    np.testing.assert_array_equal(on.indirect["floor"], off.indirect["floor"])
    assert not np.array_equal(on.direct["floor"], off.direct["floor"])
    assert on.stats["counters"]["direct_footprint_texels"] > 0


def test_sky_through_a_window_keeps_its_mean_where_every_texel_is_noisy():
    """A closed unit box lit only by a uniform sky through a 0.2 m window: every floor texel sees the
    sky through a few per cent of its hemisphere, so its 2 x 2 x 16 shadow rays disagree everywhere.
    Judged on those rays, the texels whose rays came out even (mostly all missed) kept them and the
    rest were drawn again: the floor read 0.86 of the same bake without the footprint. The edge
    evidence is independent of the kept rays and leaves the world out, so the mean holds."""
    from pdic.core.scene import World

    X, Y, Z = (np.eye(3)[i] for i in range(3))
    faces = [quad(np.zeros(3), X, Y), quad(Y, X, Z), quad(Z, Y, X), quad(np.zeros(3), Y, Z), quad(X, Z, Y),
             # the front wall (y = 0, facing in) around a window x, z in [0.4, 0.6]
             quad(np.zeros(3), 0.4 * Z, X), quad(0.6 * Z, 0.4 * Z, X),
             quad(0.4 * Z, 0.2 * Z, 0.4 * X), quad(0.6 * X + 0.4 * Z, 0.2 * Z, 0.4 * X)]
    scene = replace(quad_scene(faces, {"floor": (0, RES)}, []), world=World(np.full(3, 1.0)))
    on = bake(scene, DIRECT)
    off = bake(scene, replace(DIRECT, deviations=Deviations(direct_footprint=False)))
    a, b = on.direct["floor"], off.direct["floor"]
    assert 0.002 < b.mean() < 0.05  # E / pi of a sky of radiance 1 seen through a few per cent
    assert abs(a.mean() / b.mean() - 1.0) < 0.02
    assert on.stats["counters"]["direct_footprint_texels"] == 0  # the sky casts no edge
