"""Cornell box: PDIC against a Cycles reference in the same UV map (sample scene's "LightMap").

    .venv/bin/python bench/cornell_compare.py [--scene cornell_point] [--res 64] [--spp 1024]
        [--quality PREVIEW|FINAL] [--photons 250000] [--bounces 4] [--reference-cache DIR]
    .venv/bin/python bench/cornell_compare.py --converged [--res 256] [--quality FINAL] [--seed 0]
        [--deviations path_visibility=1,virtual_cell_minimum=1]

Prints relative RMSE over texels Cycles baked (centre inside a triangle), for
direct+indirect and indirect only, and the run times. The Cycles reference is
cached on disk keyed by scene, resolution, samples and bounces.

``--converged`` compares PDIC's indirect light, at its own default bounces, with the committed
converged pair (bench/converged_references.py: 64 bounces, 2 x 2048 spp at 64^2 per object),
the pair's noise subtracted: per 64^2 texel (PDIC's map averaged down) and on 8x8-texel block
means of a ``--res`` map (blotches: low-frequency error), with the mean bias.
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
    ap.add_argument("--converged", action="store_true",
                    help="indirect error against the converged 64-bounce pair, per texel and on 8x8 blocks")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--deviations", default="", help="switches, e.g. path_visibility=1,virtual_cell_minimum=1")
    ap.add_argument("--reference-only", action="store_true", help="only make (or load) the Cycles references")
    args = ap.parse_args(argv)
    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "sample_blends" / f"{args.scene}.blend"))
    objects = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    depsgraph = bpy.context.evaluated_depsgraph_get()
    ex = extract_scene(depsgraph, objects, "LightMap", {o.name: (args.res, args.res) for o in objects})
    if args.converged:
        return converged(ex.scene, objects, args)
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
    test_all = np.concatenate([result.as_cycles(n)[cov[n]] for n in names])
    test_ind = np.concatenate([result.indirect[n][cov[n]] for n in names])
    r_all = np.concatenate([ref_all[n][cov[n]] for n in names])
    r_ind = np.concatenate([ref_ind[n][cov[n]] for n in names])
    mask = np.ones(len(r_all), bool)
    print(f"PDIC {args.quality}: {pdic_seconds:.2f} s; Cycles {args.spp} spp: {ref_seconds:.1f} s (all), {ref_ind_seconds:.1f} s (indirect)")
    print(f"relative RMSE direct+indirect {relative_rmse(test_all, r_all, mask):.4f}, indirect {relative_rmse(test_ind, r_ind, mask):.4f}")
    print(f"mean ratio all {test_all.mean() / r_all.mean():.4f}, indirect {test_ind.mean() / r_ind.mean():.4f}")
    print(result.stats)
    return result


CONVERGED = ROOT / "bench" / "references" / "cornell_point_64_2048_64_INDIRECT.npz"
BLOCK = 8
"""Block side (texels of the --res map) of the low-frequency error."""


def converged(scene, objects, args):
    """PDIC at default bounces against the 64-bounce pair: indirect error per 64^2 texel, on 8x8 blocks, bias."""
    from pdic.bench.run import block_average, noise_corrected_error, with_deviations

    ref = np.load(CONVERGED)
    names = [o.name for o in objects]
    overrides = {"a": args.a} if args.a else {}
    if args.no_reuse:
        overrides["reuse_photon_paths"] = False
    settings = with_deviations(preset(args.quality, seed=args.seed, **overrides), args.deviations)
    t = time.process_time()
    result = bake(scene, settings)
    cpu = time.process_time() - t
    factor = args.res // 64
    rows, per_object = {}, {}
    for label, f_pdic in (("texel 64^2", factor), (f"{BLOCK}x{BLOCK} blocks", BLOCK)):
        f_ref = f_pdic // factor
        pair = [dict(images={}, coverage={}) for _ in range(2)]
        images, covered = {}, {}
        for n in names:
            cov = ref[f"cov_{n}"]
            full = cov.reshape(64 // f_ref, f_ref, 64 // f_ref, f_ref).all(axis=(1, 3))
            for side, bake_ in zip("ab", pair):
                bake_["images"][n] = block_average(ref[f"{side}_{n}"], cov, f_ref)
                bake_["coverage"][n] = full
            inside = result.centre_inside[n]
            images[n] = block_average(result.indirect[n], inside, f_pdic)
            covered[n] = inside.reshape(64 // f_ref, f_pdic, 64 // f_ref, f_pdic).any(axis=(1, 3))
        rows[label] = noise_corrected_error(images, covered, pair)
        per_object[label] = {n: noise_corrected_error({n: images[n]}, {n: covered[n]}, [
            dict(images={n: q["images"][n]}, coverage={n: q["coverage"][n]}) for q in pair]) for n in names}
        if label.startswith("texel"):
            mask = {n: pair[0]["coverage"][n] & covered[n] for n in names}
            p = np.concatenate([images[n][mask[n]] for n in names])
            r = np.concatenate([(0.5 * (pair[0]["images"][n] + pair[1]["images"][n]))[mask[n]] for n in names])
            bias = p.mean() / r.mean() - 1.0
    print(f"PDIC {args.quality} {args.res}^2 seed {args.seed}: {cpu:.1f} CPU s; reference noise "
          f"{float(ref['noise']):.4f} (relative, of the pair's mean at 64^2)")
    for label, err in rows.items():
        print(f"indirect error {label}: {err:.4f}  (" + ", ".join(f"{n} {e:.4f}" for n, e in per_object[label].items())
              + ")")
    print(f"indirect mean bias {bias:+.4f}")
    return rows


if __name__ == "__main__":
    main()
