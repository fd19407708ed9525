"""Every mechanism beyond the paper has a switch (docs/DEVIATIONS.md): off, it does no work."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pdic.core.pipeline import bake
from pdic.core.settings import Deviations, preset

from scenes import lamp_box

FINAL = preset("FINAL", photons=4000, max_bounces=3, threads=1, hemisphere_theta=6, hemisphere_phi=12)
REUSE = replace(FINAL, reuse_photon_paths=True)
"""Final with the paper's photon-path reuse, where the virtual-ray deviations act."""


def _box():
    # 24 texels: R_min (2 texels) is below R_max, so zones differ in size
    return lamp_box(24)


def _bake(settings, **switches):
    result = bake(_box(), replace(settings, deviations=Deviations(**switches)))
    for name, image in result.lightmaps.items():
        assert np.isfinite(image).all(), name
    return result, result.stats["counters"]


@pytest.fixture(scope="module")
def default():
    return _bake(FINAL)


@pytest.fixture(scope="module")
def reused():
    return _bake(REUSE)


@pytest.mark.parametrize("switch, counter, reuse", [
    ("texel_validity", "validity_rays", False),
    ("probe_rays", "refine_probe_rays", True),
    ("zone_visibility", "refine_visibility_rays", True),
    ("wall_sectors", "refine_wall_rays", False),
    ("adaptive_gathering", "refine_extra_gathers", False),
    ("gathered_radius", "refine_wall_rays", False),
    ("crevice_records", "crevice_samples", False),
    ("clamp_recovery", "photons_uncovered_after_clamp", False),
])
def test_a_deviation_switched_off_casts_none_of_its_rays(default, reused, switch, counter, reuse):
    assert (reused if reuse else default)[1][counter] > 0
    _, counters = _bake(REUSE if reuse else FINAL, **{switch: False})
    assert counters[counter] == 0


def test_standard_gathering_casts_no_virtual_ray_and_reuse_does(default, reused):
    assert default[1]["refine_virtual_rays"] == default[1]["refine_probe_rays"] == 0
    assert reused[1]["refine_virtual_rays"] > 0 and reused[1]["refine_probe_rays"] > 0


def test_without_wall_sectors_pass_2_casts_no_wall_rays():
    _, counters = _bake(preset("PREVIEW", photons=4000, max_bounces=3, threads=1), wall_sectors=False,
                        surface_coverage=False)
    assert counters["wall_rays"] == 0


def test_without_thinning_every_zone_photon_lends_a_virtual_ray():
    # 8 cells and whole zones (no probe radius): zones hold more than 16 photons
    coarse = replace(REUSE, photons=20_000, hemisphere_theta=2, hemisphere_phi=4)
    _, thinned = _bake(coarse, probe_rays=False)
    _, every = _bake(coarse, probe_rays=False, virtual_thinning=False)
    assert every["refine_virtual_rays"] > thinned["refine_virtual_rays"]


@pytest.mark.parametrize("switch, reuse", [("harmonic_cell_radiance", True), ("gradient_limiting", False),
                                           ("neighbour_clamp", False), ("nearest_photon_fallback", False),
                                           ("fine_zones", False), ("gap_fill", True), ("leave_one_out", False),
                                           ("surface_coverage", False), ("gathered_radius", False),
                                           ("corner_gathering", False)])
def test_switching_a_deviation_off_changes_the_bake_and_keeps_it_finite(default, reused, switch, reuse):
    result, _ = _bake(REUSE if reuse else FINAL, **{switch: False})
    base = reused if reuse else default
    changed = any(not np.array_equal(result.lightmaps[n], base[0].lightmaps[n]) for n in result.lightmaps)
    cache, before = result.cache, base[0].cache
    records_changed = len(cache) != len(before) or not np.array_equal(cache.R, before.R)
    assert changed or records_changed


def test_zero_hole_rounds_place_no_hole_records():
    _, counters = _bake(FINAL, hole_rounds=0)
    assert counters["hole_records"] == 0


def test_default_deviations_are_todays_bake(default):
    result, _ = _bake(FINAL, **{f: getattr(Deviations(), f) for f in Deviations.__dataclass_fields__})
    for name in result.lightmaps:
        np.testing.assert_array_equal(result.lightmaps[name], default[0].lightmaps[name])


def test_a_cached_bake_is_not_reused_for_other_deviations(tmp_path, default):
    from pdic.core.bake_cache import BakeCache

    store = BakeCache(tmp_path / "cache")
    bake(_box(), FINAL, cache=store)
    switched = bake(_box(), replace(FINAL, deviations=Deviations(harmonic_cell_radiance=False)), cache=store)
    alone, _ = _bake(FINAL, harmonic_cell_radiance=False)
    for name in alone.lightmaps:
        np.testing.assert_array_equal(switched.lightmaps[name], alone.lightmaps[name])


def test_the_virtual_cell_minimum_sends_real_rays_into_cells_one_photon_reached(reused):
    _, on = _bake(REUSE, virtual_cell_minimum=True)
    off = reused[1]
    assert on["refine_cells_virtual"] < off["refine_cells_virtual"]
    assert on["refine_rays_cast"] > off["refine_rays_cast"]


def test_path_visibility_casts_one_occlusion_ray_per_virtual_ray_and_none_when_off(reused):
    assert reused[1]["refine_path_visibility_rays"] == 0
    _, on = _bake(REUSE, path_visibility=True)
    assert 0 < on["refine_path_visibility_rays"] <= on["refine_rays_cast"]
    assert on["refine_virtual_rays"] <= on["refine_path_visibility_rays"]


def test_the_zone_photon_floor_widens_preview_zones_and_leaves_final_alone(default):
    preview = preset("PREVIEW", photons=4000, max_bounces=3, threads=1)
    on, _ = _bake(preview)
    off, _ = _bake(preview, zone_photon_floor=False)
    assert len(on.cache) < len(off.cache) and on.cache.R.mean() > off.cache.R.mean()
    assert on.cache.photons_used.min() > off.cache.photons_used.min()
    final_off, _ = _bake(FINAL, zone_photon_floor=False)
    for name in final_off.lightmaps:  # Final's records gather their own E_k: R_min stays their floor
        np.testing.assert_array_equal(final_off.lightmaps[name], default[0].lightmaps[name])
