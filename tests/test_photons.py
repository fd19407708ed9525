"""Pass 1 and pass 2 on closed forms: photon flux, white furnace, Algorithm 1 invariants."""
import numpy as np
import pytest

from pdic.core import emission
from pdic.core.executor import Executor
from pdic.core.density import PhotonDensity
from pdic.core.irradiance_cache import CacheParameters, cache_from_photons
from pdic.core.photons import PhotonMap, trace_photons
from pdic.core.rays import RayCaster
from pdic.core.scene import AreaLight, PointLight, SpotLight, SunLight, World

from scenes import furnace, lit, quad


def _floor_scene(light=None, world=None):
    tris = quad([-1, -1, 0], [2, 0, 0], [0, 2, 0])
    return lit(tris, *((light,) if light else ()), world=world)


def _emitted_power(scene, photons=20_000):
    plan = emission.plan(scene, photons)
    total = np.zeros(3)
    for i, batch in enumerate(plan.batches(4096)):
        _, _, power, _ = emission.emit(scene, batch, np.random.default_rng(i))
        total += power.sum(0)
    return total, plan


@pytest.mark.parametrize("light, flux", [
    (PointLight("p", np.array([0, 0, 1.0]), np.array([100.0, 50, 25])), [100, 50, 25]),
    (AreaLight("a", np.array([0, 0, 1.0]), np.array([0, 0, -1.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]),
               0.5, 0.25, "RECTANGLE", np.array([3.0, 3, 3])), [3 * np.pi * 0.125] * 3),
    (AreaLight("d", np.array([0, 0, 1.0]), np.array([0, 0, -1.0]), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]),
               0.5, 0.5, "DISK", np.array([2.0, 2, 2])), [2 * np.pi * np.pi * 0.0625] * 3),
])
def test_emitted_photon_flux_equals_light_power(light, flux):
    total, plan = _emitted_power(_floor_scene(light))
    assert plan.total == 20_000
    assert np.allclose(total, flux, rtol=1e-9)


def test_spot_emits_its_cone_share_of_point_power():
    # Hard 90-degree cone (half angle 45): flux = P/(4 pi) * 2 pi (1 - cos 45).
    spot = SpotLight("s", np.array([0, 0, 1.0]), np.array([0, 0, -1.0]), np.array([40.0, 40, 40]),
                     np.pi / 4, 0.0)
    total, _ = _emitted_power(_floor_scene(spot))
    assert total[0] == pytest.approx(40 / (4 * np.pi) * 2 * np.pi * (1 - np.cos(np.pi / 4)), rel=1e-3)


@pytest.mark.parametrize("light, world, expected", [
    (SunLight("sun", np.array([0, 0, 1.0]), np.array([3.0, 3, 3])), None, 3.0),
    (SunLight("tilted", np.array([0, 0.6, 0.8]), np.array([2.0, 2, 2])), None, 1.6),
    (None, World(np.array([0.5, 0.5, 0.5])), np.pi * 0.5),
    (PointLight("p", np.array([0, 0, 10.0]), np.array([4000.0] * 3)), None, 4000 / (4 * np.pi * 100)),
])
def test_first_hit_photon_density_gives_analytic_irradiance(light, world, expected):
    scene = _floor_scene(light, world)
    caster = RayCaster(scene.geometry.positions)
    pm, stats = trace_photons(scene, caster, 200_000, 1, seed=3)
    first = pm.bounce == 0
    top = pm.n[:, 2] > 0.99  # the side facing up (the world also lights the underside)
    central = first & top & (np.abs(pm.p[:, 0]) < 0.5) & (np.abs(pm.p[:, 1]) < 0.5)
    E = pm.power[central, 0].sum() / 1.0  # flux into the central 1 x 1 square
    assert E == pytest.approx(expected, rel=0.05)
    assert np.all(np.abs(pm.n[first, 2]) > 0.99)  # stored with the normal of the side hit


def test_photons_leaving_an_open_scene_stop_at_once():
    scene = _floor_scene(SunLight("sun", np.array([0, 0, 1.0]), np.array([1.0, 1, 1])))
    pm, stats = trace_photons(scene, RayCaster(scene.geometry.positions), 10_000, 5, seed=0)
    # A photon that misses the floor, or leaves it after a bounce, costs exactly one ray and is dropped:
    # every ray either hits the floor once (stored) or escapes.
    assert stats.rays == stats.stored + stats.escaped
    assert pm.bounce.max() == 0
    survivors = stats.rays - stats.emitted  # bounced photons (Russian roulette with albedo 0.8)
    assert survivors == pytest.approx(0.8 * stats.stored, rel=0.05)


def test_path_links_point_to_the_previous_hit():
    scene = furnace(0.8, 1.0, subdivisions=2)
    pm, _ = trace_photons(scene, RayCaster(scene.geometry.positions), 5_000, 6, seed=1, executor=Executor(2))
    linked = pm.prev >= 0
    assert linked.any()
    prev = pm.prev[linked]
    assert np.all(pm.bounce[linked] == pm.bounce[prev] + 1)
    assert np.allclose(pm.last_hit[linked], pm.p[prev], atol=1e-4)


def test_bytes_per_photon_is_as_documented():
    pm = PhotonMap.empty()
    assert PhotonMap.BYTES_PER_PHOTON == 101
    scene = furnace(0.5, 1.0, subdivisions=1)
    pm, _ = trace_photons(scene, RayCaster(scene.geometry.positions), 1000, 3, seed=0)
    assert pm.nbytes == len(pm) * PhotonMap.BYTES_PER_PHOTON


def test_white_furnace_cache_converges_to_analytic():
    # Uniform emission L and albedo rho in a closed sphere: E = pi L / (1 - rho); indirect = pi L rho / (1 - rho).
    rho, L = 0.5, 1.0
    scene = furnace(rho, L, subdivisions=3)
    caster = RayCaster(scene.geometry.positions)
    pm, _ = trace_photons(scene, caster, 200_000, 40, seed=5, executor=Executor(2))
    params = CacheParameters(a=0.5, r_nearest=16, R_min=0.05, R_max=0.5)
    cache, zones, lighting, stats = cache_from_photons(PhotonDensity(pm), params, seed=0)
    expected = np.pi * L * rho / (1 - rho)
    assert stats.records == len(cache) > 10
    assert np.mean(cache.E[:, 0]) == pytest.approx(expected, rel=0.05)
    assert np.all(lighting.w_sum >= 1 / params.a - 1e-9)  # Algorithm 1 leaves no photon uncovered
    assert np.mean(lighting.E_indirect()[:, 0]) == pytest.approx(expected, rel=0.05)


def test_photon_map_is_read_only_even_after_a_round_trip_through_pickle():
    import pickle

    scene = _floor_scene(PointLight("p", np.array([0, 0, 1.0]), np.full(3, 10.0)))
    pm, _ = trace_photons(scene, RayCaster(scene.geometry.positions), 500, 2, seed=0)
    for photons in (pm, pickle.loads(pickle.dumps(pm))):
        with pytest.raises(ValueError, match="read-only"):
            photons.p[0] = 0.0
        with pytest.raises(ValueError, match="read-only"):
            photons.prev[:] = -1


def test_bounce_counter_holds_the_largest_allowed_max_bounces_and_settings_reject_more():
    """Photons store their bounce in a uint8: 255 bounces fit, 256 would wrap to 0 ('direct')."""
    from pdic.core.settings import BakeSettings

    assert BakeSettings(max_bounces=255).max_bounces == 255
    with pytest.raises(ValueError, match="max_bounces=256"):
        BakeSettings(max_bounces=256)
    # A white closed sphere: no photon escapes or dies, so each makes all 255 bounces.
    scene = furnace(1.0, 1.0, subdivisions=1)
    pm, _ = trace_photons(scene, RayCaster(scene.geometry.positions), 4, 255, seed=0)
    assert pm.bounce.dtype == np.uint8
    assert int(pm.bounce.max()) == 255
    linked = pm.prev >= 0
    assert np.all(pm.bounce[linked] == pm.bounce[pm.prev[linked]] + 1)


def test_records_split_over_threads_equal_one_thread():
    """Record placement's density estimates shared between threads give each record the same zone,
    weights and E_k, bit for bit, as one thread (walls, coverage and leave-one-out included)."""
    scene = furnace(0.5, 1.0, subdivisions=3)
    pm, _ = trace_photons(scene, RayCaster(scene.geometry.positions), 20_000, 8, seed=2, executor=Executor(2))
    one, two = PhotonDensity(pm, workers=1), PhotonDensity(pm, workers=2)
    rng = np.random.default_rng(0)
    at = rng.choice(len(pm), 300, replace=False)
    p_k, n_k, R_k = one.p[at], one.n[at].astype(np.float64), rng.uniform(0.1, 0.4, 300)
    from pdic.core.constants import WALL_RAYS

    sectors = (300, WALL_RAYS)
    wall = np.where(rng.random(sectors) < 0.2, rng.uniform(0.02, 0.3, sectors), np.inf).astype(np.float32)
    coverage = rng.uniform(0.5, 1.0, 300)
    for extra in ({}, {"wall": wall, "coverage": coverage, "own": at}):
        a, b = one.records(p_k, n_k, R_k, 0.5, **extra), two.records(p_k, n_k, R_k, 0.5, **extra)
        for name in ("lengths", "photons", "w", "E_k", "used"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert a.E_k.sum() > 0


def test_photon_reach_is_the_distance_to_the_count_th_photon_on_the_surface_faced():
    """The zone-photon floor's distance: the count-th nearest indirect photon whose normal agrees,
    checked against a brute-force sort (where the oversampled query holds fewer, the farthest
    photon it holds: a lower bound); photons on the other side of a surface are not counted."""
    from pdic.core.constants import R_OVERSAMPLE, SAME_SURFACE_COS

    scene = furnace(0.5, 1.0, subdivisions=3)
    pm, _ = trace_photons(scene, RayCaster(scene.geometry.positions), 20_000, 8, seed=3, executor=Executor(1))
    density = PhotonDensity(pm)
    at = np.random.default_rng(1).choice(len(pm), 50, replace=False)
    p_k, n_k = density.p[at], density.n[at].astype(np.float64)
    reach = density.photon_reach(p_k, n_k, 16)
    exact = 0
    for k in range(len(at)):
        d = np.linalg.norm(density.p - p_k[k], axis=1)
        facing = np.einsum("ij,j->i", density.n.astype(np.float64), n_k[k])  # as photon_reach sums it
        ok = density.is_indirect & (facing >= SAME_SURFACE_COS)
        nearest = np.argsort(d)[:R_OVERSAMPLE * 16]
        if ok[nearest].sum() >= 16:
            assert reach[k] == pytest.approx(np.sort(d[ok])[15], rel=1e-12)
            exact += 1
        else:
            assert reach[k] == pytest.approx(d[nearest].max(), rel=1e-12) and reach[k] < np.sort(d[ok])[15]
    assert exact > 40
    flipped = density.photon_reach(p_k, -n_k, 16)  # the sphere's outside: no photon faces it
    assert np.all(flipped >= reach)
