"""The paper's Cornell box (one point light) against Cycles at 16,384 samples, in the same UV map.

The reference (bench/references/, made by ``bench/cornell_compare.py --reference-only``
with the bpy wheel's Cycles on the CPU, adaptive sampling off, 4 diffuse bounces)
holds Diffuse Indirect at 16,384 spp and Diffuse Direct at 256 spp (a point light's
direct light converges in a few samples). Its own per-texel noise is about
2.9 / sqrt(16384) = 2.3 % of the mean, so relative RMSE cannot go much below that.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
RESOLUTION, SPP, BOUNCES = 64, 16384, 4


@pytest.fixture(scope="module")
def cornell():
    import bpy

    import cycles_reference as cc
    from pdic.pdic_addon.extract import extract_scene

    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "sample_blends" / "cornell_point.blend"))
    objects = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    extraction = extract_scene(bpy.context.evaluated_depsgraph_get(), objects, "LightMap",
                               {o.name: (RESOLUTION, RESOLUTION) for o in objects})
    refs = ROOT / "bench" / "references"
    direct, coverage, _ = cc.reference(objects, RESOLUTION, cc.DIRECT_SPP, {"DIRECT"}, BOUNCES, refs, "cornell_point")
    indirect, _, _ = cc.reference(objects, RESOLUTION, SPP, {"INDIRECT"}, BOUNCES, refs, "cornell_point")
    yield extraction.scene, direct, indirect, coverage
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _errors(result, direct, indirect, coverage):
    """(direct+indirect, indirect) relative RMSE over the texels Cycles baked, in Cycles' convention
    (``BakeResult.as_cycles``: the floor under the blocks black, as Cycles bakes it)."""
    names = list(coverage)
    pick = lambda images: np.concatenate([images[n][..., :3][coverage[n]] for n in names])  # noqa: E731
    ref_all = pick({n: direct[n] + indirect[n] for n in names})
    ref_ind = pick(indirect)
    rmse = lambda t, r: float(np.sqrt(((t - r) ** 2).mean()) / r.mean())  # noqa: E731
    return rmse(pick({n: result.as_cycles(n) for n in names}), ref_all), rmse(pick(result.indirect), ref_ind)


@pytest.mark.slow
def test_preview_cache_is_within_15_percent_of_cycles_and_leaves_no_texel_dark(cornell):
    from pdic.core.pipeline import bake
    from pdic.core.settings import preset

    scene, direct, indirect, coverage = cornell
    result = bake(scene, preset("PREVIEW", photons=250_000, max_bounces=BOUNCES))
    _, err_indirect = _errors(result, direct, indirect, coverage)
    counters = result.stats["counters"]
    assert err_indirect <= 0.15
    assert counters["texel_points_unfilled"] == 0  # every texel outside geometry got a record
    assert counters["records"] > 500 and "refine_cells" not in counters  # pass 3 skipped in Preview


@pytest.mark.slow
def test_final_matches_cycles_within_3_percent_overall_and_8_percent_indirect(cornell):
    from pdic.core.pipeline import bake
    from pdic.core.settings import preset

    scene, direct, indirect, coverage = cornell
    result = bake(scene, preset("FINAL", max_bounces=BOUNCES))
    err_all, err_indirect = _errors(result, direct, indirect, coverage)
    assert err_all <= 0.03
    assert err_indirect <= 0.08


@pytest.mark.slow
def test_photon_path_reuse_casts_35_percent_fewer_rays_at_no_loss_of_accuracy(cornell):
    # The paper's Table 2 setting: 250k photons, 4 bounces, a few hundred cells per record.
    from pdic.core.pipeline import bake
    from pdic.core.settings import Deviations, preset

    scene, direct, indirect, coverage = cornell
    runs = {}
    for reuse in (True, False):
        # One gather per record, as the paper's (adaptive gathering's later rounds would cast every cell),
        # and pass 2's records as Algorithm 1 places them: clamp recovery's records sit where zones were
        # clamped small and hold few photons to lend (with it 32.8 % fewer rays, session 36). The texels' hole
        # records as section 3.4 places them: thin-coverage runs with standard gathering only.
        settings = preset("FINAL", photons=250_000, max_bounces=BOUNCES, hemisphere_theta=12, hemisphere_phi=24,
                          reuse_photon_paths=reuse,
                          deviations=Deviations(adaptive_gathering=False, clamp_recovery=False, thin_coverage=False))
        result = bake(scene, settings)
        runs[reuse] = (result.stats["counters"], _errors(result, direct, indirect, coverage)[1])
    (ours, err_ours), (standard, err_standard) = runs[True], runs[False]
    assert standard["refine_rays_cast"] == standard["refine_cells"]  # standard gathering casts every cell
    saved = 1.0 - ours["refine_rays_cast"] / standard["refine_rays_cast"]
    assert saved >= 0.35
    assert err_ours <= 1.10 * err_standard
