"""Cornell box: PDIC against a Cycles reference in the same UV map (sample scene's "LightMap").

    .venv/bin/python bench/cornell_compare.py [--scene cornell_point] [--res 64] [--spp 1024]
        [--quality PREVIEW|FINAL] [--photons 250000] [--bounces 4] [--reference-cache DIR]

Prints relative RMSE over texels Cycles baked (centre inside a triangle), for
direct+indirect and indirect only, and the run times. The Cycles reference is
cached on disk keyed by scene, resolution, samples and bounces.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import pdic_bootstrap  # noqa: E402

pdic_bootstrap.load()
import bpy  # noqa: E402

from pdic.bench.cycles_reference import DIRECT_SPP, reference  # noqa: E402,F401
from pdic.core.pipeline import bake  # noqa: E402
from pdic.core.settings import preset  # noqa: E402
from pdic.pdic_addon.extract import extract_scene  # noqa: E402


def relative_rmse(test: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> float:
    """sqrt(mean (test - ref)^2) / mean(ref) over masked texels, luminance-free (all channels)."""
    d = (test[mask] - ref[mask]) ** 2
    return float(np.sqrt(d.mean()) / max(ref[mask].mean(), 1e-30))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="cornell_point")
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--quality", default="PREVIEW")
    ap.add_argument("--photons", type=int, default=250_000)
    ap.add_argument("--bounces", type=int, default=4)
    ap.add_argument("--a", type=float, default=None)
    ap.add_argument("--no-reuse", action="store_true", help="standard final gathering (every cell casts a ray)")
    ap.add_argument("--no-gradients", action="store_true")
    ap.add_argument("--reference-cache", default=str(ROOT / "bench" / "references"))
    ap.add_argument("--reference-only", action="store_true", help="only make (or load) the Cycles references")
    args = ap.parse_args(argv)
    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "sample_blends" / f"{args.scene}.blend"))
    objects = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    depsgraph = bpy.context.evaluated_depsgraph_get()
    ex = extract_scene(depsgraph, objects, "LightMap", {o.name: (args.res, args.res) for o in objects})
    overrides = dict(photons=args.photons, max_bounces=args.bounces)
    if args.a:
        overrides["a"] = args.a
    if args.no_reuse:
        overrides["reuse_photon_paths"] = False
    if args.no_gradients:
        overrides["gradients"] = False
    settings = preset(args.quality, **overrides)
    cache_dir = Path(args.reference_cache)
    if args.reference_only:
        reference(objects, args.res, DIRECT_SPP, {"DIRECT"}, args.bounces, cache_dir, args.scene)
        reference(objects, args.res, args.spp, {"INDIRECT"}, args.bounces, cache_dir, args.scene)
        return None
    t = time.perf_counter()
    result = bake(ex.scene, settings)
    pdic_seconds = time.perf_counter() - t
    # Direct light from a point light converges within a few samples; indirect needs the samples.
    ref_dir, cov, ref_dir_seconds = reference(objects, args.res, DIRECT_SPP, {"DIRECT"}, args.bounces,
                                              cache_dir, args.scene)
    ref_ind, _, ref_ind_seconds = reference(objects, args.res, args.spp, {"INDIRECT"}, args.bounces, cache_dir,
                                            args.scene)
    ref_all = {n: ref_dir[n] + ref_ind[n] for n in ref_dir}
    ref_seconds = ref_dir_seconds + ref_ind_seconds
    names = list(ref_all)
    test_all = np.concatenate([result.lightmaps[n][..., :3][cov[n]] for n in names])
    test_ind = np.concatenate([result.indirect[n][cov[n]] for n in names])
    r_all = np.concatenate([ref_all[n][cov[n]] for n in names])
    r_ind = np.concatenate([ref_ind[n][cov[n]] for n in names])
    mask = np.ones(len(r_all), bool)
    print(f"PDIC {args.quality}: {pdic_seconds:.2f} s; Cycles {args.spp} spp: {ref_seconds:.1f} s (all), {ref_ind_seconds:.1f} s (indirect)")
    print(f"relative RMSE direct+indirect {relative_rmse(test_all, r_all, mask):.4f}, indirect {relative_rmse(test_ind, r_ind, mask):.4f}")
    print(f"mean ratio all {test_all.mean() / r_all.mean():.4f}, indirect {test_ind.mean() / r_ind.mean():.4f}")
    print(result.stats)
    return result


if __name__ == "__main__":
    main()
