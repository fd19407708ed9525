"""The world's light through the records (deviation: sky-gathering): smooth where shadow rays per texel
are grain, exact in the open, and out of the way where it cannot apply."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pdic.core.pipeline import bake
from pdic.core.scene import World
from pdic.core.settings import Deviations, preset

from scenes import quad, quad_scene

FINAL = preset("FINAL", threads=2)
SKY = np.array([1.0, 0.5, 0.25])
X, Y, Z = (np.eye(3)[i] for i in range(3))


def _window_box(res: int = 32, glass: float = 0.0):
    """A closed unit box lit only by a uniform sky through a 0.2 m window in its front wall; the floor baked.
    glass > 0: a pane passing that share of the light fills the window."""
    faces = [quad(np.zeros(3), X, Y), quad(Y, X, Z), quad(Z, Y, X), quad(np.zeros(3), Y, Z), quad(X, Z, Y),
             quad(np.zeros(3), 0.4 * Z, X), quad(0.6 * Z, 0.4 * Z, X),
             quad(0.4 * Z, 0.2 * Z, 0.4 * X), quad(0.6 * X + 0.4 * Z, 0.2 * Z, 0.4 * X)]
    if glass:
        faces.append(quad(0.4 * X + 0.4 * Z, 0.2 * Z, 0.2 * X))
    scene = replace(quad_scene(faces, {"floor": (0, res)}, []), world=World(np.full(3, 1.0)))
    if glass:
        tau = np.zeros(scene.geometry.count, np.float32)
        tau[-2:] = glass
        scene = replace(scene, geometry=replace(scene.geometry, transmission=tau))
    return scene


def _open_ground(res: int = 8):
    return replace(quad_scene([quad(np.zeros(3), X, Y)], {"floor": (0, res)}, []), world=World(SKY))


def _relative_rms(test: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    t, r = test.mean(axis=-1)[mask], reference.mean(axis=-1)[mask]
    return float(np.sqrt(np.mean((t - r) ** 2)) / r.mean())


def test_sky_through_a_window_is_gathered_by_the_records_smooth_and_with_its_mean():
    """Every floor texel sees the sky through a few per cent of its hemisphere: 2 x 2 x 16 shadow rays
    per texel are 140 % grain against 1,024 per sample. The records' gathering rays that escape read
    the same sky, and Equation 3 spreads it: measured 22 % against that reference, whose own grain is
    about 18 %, and the mean within 1 %."""
    scene = _window_box()
    gathered = bake(scene, FINAL)
    per_texel = bake(scene, replace(FINAL, deviations=Deviations(sky_gathering=False)))
    reference = bake(scene, replace(FINAL, direct_samples=1024, deviations=Deviations(sky_gathering=False)))
    mask = reference.centre_inside["floor"]
    ref = reference.direct["floor"]
    assert gathered.stats["counters"]["sky_gathered"] == 1
    assert gathered.stats["counters"]["shadow_rays_world"] == 0  # no texel casts a ray at the sky
    assert per_texel.stats["counters"]["sky_gathered"] == 0
    assert per_texel.stats["counters"]["shadow_rays_world"] > 0
    assert 0.002 < ref[mask].mean() < 0.05
    assert abs(gathered.direct["floor"][mask].mean() / ref[mask].mean() - 1.0) < 0.05
    smooth = _relative_rms(gathered.direct["floor"], ref, mask)
    grainy = _relative_rms(per_texel.direct["floor"], ref, mask)
    assert smooth < 0.4
    assert grainy > 3 * smooth
    # The indirect light is the records' as before; only the sky moved from shadow rays to their gathers.
    ratio = gathered.indirect["floor"][mask].mean() / per_texel.indirect["floor"][mask].mean()
    assert abs(ratio - 1.0) < 0.05


def test_the_sky_through_glass_is_gathered_as_the_shadow_rays_see_it():
    """A pane passing 60 % fills the window: a gathering ray that meets it brings 0.6 of the sky beyond
    (the texels' shadow rays pass it the same way, deviation: transparent-shadows)."""
    open_window, glazed = bake(_window_box(), FINAL), bake(_window_box(glass=0.6), FINAL)
    reference = bake(_window_box(glass=0.6), replace(FINAL, direct_samples=1024,
                                                     deviations=Deviations(sky_gathering=False)))
    mask = reference.centre_inside["floor"]
    assert glazed.stats["counters"]["sky_gathered"] == 1 and glazed.stats["counters"]["shadow_rays_world"] == 0
    ref = reference.direct["floor"][mask].mean()
    assert abs(glazed.direct["floor"][mask].mean() / ref - 1.0) < 0.05
    assert abs(glazed.direct["floor"][mask].mean() / open_window.direct["floor"][mask].mean() - 0.6) < 0.05
    assert _relative_rms(glazed.direct["floor"], reference.direct["floor"], mask) < 0.4


def test_open_ground_reads_the_sky_exactly():
    """A plane under a uniform sky sees all of it: every gathering ray escapes, E_k = pi L exactly, no
    gradient, and each texel holds L (E / pi), as the per-texel shadow rays give."""
    result = bake(_open_ground(), FINAL)
    mask = result.centre_inside["floor"]
    assert result.stats["counters"]["sky_gathered"] == 1
    assert result.stats["counters"]["records_total"] > 0
    np.testing.assert_allclose(result.direct["floor"][mask], np.broadcast_to(SKY, (int(mask.sum()), 3)), rtol=1e-6)
    assert np.all(result.indirect["floor"][mask] == 0.0)


def test_without_records_the_texels_cast_their_own_rays_at_the_sky():
    """No photon stayed (one photon, seed 0: it missed), so no record gathers the sky: the texels that
    were to read it from the records cast their shadow rays after all, and the sky is not lost."""
    result = bake(_open_ground(), replace(FINAL, photons=1, seed=0))
    counters = result.stats["counters"]
    mask = result.centre_inside["floor"]
    assert counters["photons_stored"] == 0 and counters["sky_gathered"] == 1
    assert counters["shadow_rays_world"] > 0
    np.testing.assert_allclose(result.direct["floor"][mask], np.broadcast_to(SKY, (int(mask.sum()), 3)), rtol=1e-6)


def test_preview_records_gather_the_sky_with_rays_of_their_own():
    """Preview's records gather nothing else: they cast 512 rays each that only ask whether they escape.
    The window box's floor: 26 % RMS against the 1,024-ray reference (8 shadow rays per sample: 199 %),
    its mean 6 % bright (Preview's photon-sized zones spread the patch under the window; Final 0.99)."""
    scene = _window_box()
    preview = preset("PREVIEW", threads=2)
    gathered = bake(scene, preview)
    per_texel = bake(scene, replace(preview, deviations=Deviations(sky_gathering=False)))
    reference = bake(scene, replace(FINAL, direct_samples=1024, deviations=Deviations(sky_gathering=False)))
    mask = reference.centre_inside["floor"]
    counters = gathered.stats["counters"]
    assert counters["sky_gathered"] == 1 and counters["shadow_rays_world"] == 0 and counters["sky_rays"] > 0
    ref = reference.direct["floor"]
    assert abs(gathered.direct["floor"][mask].mean() / ref[mask].mean() - 1.0) < 0.1
    smooth = _relative_rms(gathered.direct["floor"], ref, mask)
    assert smooth < 0.45
    assert _relative_rms(per_texel.direct["floor"], ref, mask) > 3 * smooth


@pytest.mark.parametrize("case", ["direct only", "photon paths", "switched off"])
def test_the_sky_stays_with_the_texels_where_records_cannot_gather_it(case):
    """A bake without indirect light has no records; virtual rays carry no sky. Each keeps the per-texel
    sky."""
    scene = _open_ground()
    settings = FINAL
    if case == "direct only":
        settings = replace(FINAL, indirect=False)
    elif case == "photon paths":
        settings = replace(FINAL, reuse_photon_paths=True)
    else:
        settings = replace(FINAL, deviations=Deviations(sky_gathering=False))
    result = bake(scene, settings)
    counters = result.stats["counters"]
    mask = result.centre_inside["floor"]
    assert counters["sky_gathered"] == 0
    assert counters["shadow_rays_world"] > 0
    np.testing.assert_allclose(result.direct["floor"][mask].mean(axis=0), SKY, rtol=0.02)


def test_caches_joined_at_once_hold_what_joining_them_pair_by_pair_held():
    """IrradianceCache.concatenate, which a bake's hole rounds and targets join through: each column in
    order, and a part that gathered no sky reads 0 there (the records of other rounds did gather it)."""
    from pdic.core.irradiance_cache import IrradianceCache

    rng = np.random.default_rng(2)

    def part(k, sky):
        fields = dict(p=rng.random((k, 3)), n=np.tile([0.0, 0, 1], (k, 1)), E=rng.random((k, 3)), R=rng.random(k))
        if sky:
            fields.update(E_sky=rng.random((k, 3)), grad_r_sky=rng.random((k, 3, 3)), grad_t_sky=rng.random((k, 3, 3)))
        return IrradianceCache(**fields)

    parts = [part(5, True), part(3, False), part(4, True)]
    joined = IrradianceCache.concatenate(parts)
    assert len(joined) == 12 and np.array_equal(joined.p, np.concatenate([c.p for c in parts]))
    assert np.array_equal(joined.E_sky[:5], parts[0].E_sky) and np.array_equal(joined.E_sky[8:], parts[2].E_sky)
    assert not joined.E_sky[5:8].any() and not joined.grad_t_sky[5:8].any()
    assert IrradianceCache.concatenate([part(2, False), part(1, False)]).E_sky is None
