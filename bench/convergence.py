"""Indirect mean bias and error of PDIC against the converged Cycles references (64 bounces).

    .venv/bin/python bench/convergence.py [--scenes cornell,occluded,sponza] [--quality FINAL]
        [--bounces 6,64] [--density-control 0] [--photons N] [--figure5]
        [--deviations path_visibility=1,virtual_cell_minimum=1] [--set r_min_texels=3]

Needs bench/converged_references.py's output (references in bench/references/, the one-object
core scenes in bench/results/converged/). Per bake: bias = sum PDIC / sum reference - 1 over the
texels both cover, the noise-corrected relative RMS error (bench/run.py), the same error over
*comparable* texels (``bench.run.comparable_texels``: no other face within two ray offsets of a
sample, where Cycles' bake rays see other geometry than PDIC's; chart edges in), over *interior*
texels only (``bench.run.interior_texels``) and over texels not buried (no part of the footprint
inside closed geometry, ``BakeResult.buried``), the 8x8 blocks judged and those off by more than 20 %
(``bench.run.blocks_off``, over all texels, comparable ones and those not buried; the last also by the
texels a block holds, ``bench.run.blocks_off_by_fill``), photons stored and the bake's CPU
seconds (``threads=1``). ``--figure5`` runs bench/run.py's [Chr99]-vs-Preview comparison against the same
references instead.
"""
from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
from bench import run as bench_run  # noqa: E402  (loads pdic and bpy)

from pdic.core.pipeline import bake  # noqa: E402
from pdic.core.settings import preset  # noqa: E402

REFERENCES = ROOT / "bench" / "references"
SCENES = ROOT / "bench" / "results" / "converged"
FILES = {"cornell": "cornell_point_64_2048_64_INDIRECT.npz", "cornell_area": "cornell_area_64_2048_64_INDIRECT.npz",
         "occluded": "occluded_one_d4_2048x2_64_INDIRECT.npz", "sponza": "sponza_one_d4_512x2_64_INDIRECT.npz",
         "occluded_held": "occluded_held_one_d4_1024x2_64_INDIRECT.npz",
         "sponza_held": "sponza_held_one_d4_512x2_64_INDIRECT.npz"}
"""``*_held``: the scene at 4 texels/m held (maps grown to 272^2 and 796^2); the others' maps are
sized from the surface area (bench/converged_references.py)."""


def load(name: str, tag: str = ""):
    """(core scene, reference pair as two dicts of images/coverage, the reference's noise).
    tag : the references' file-name tag (bench/converged_references.py --tag), "" for the committed ones."""
    pair, noise = bench_run.reference_pair(REFERENCES / FILES[name].replace("_INDIRECT", f"{tag}_INDIRECT"))
    if name in bench_run.CORNELL_BLENDS:
        scene = bench_run.cornell_scene(blend=bench_run.CORNELL_BLENDS[name])[1]
    else:
        tagged = SCENES / f"{name}{tag}.pkl"  # the same UVs (the unwrap is deterministic): either will do
        scene = pickle.loads((tagged if tagged.exists() else SCENES / f"{name}.pkl").read_bytes())
    return scene, pair, noise


def measure(name: str, scene, pair, quality: str, overrides: dict, switches: str = "", masks=None,
            seeds=(0,)) -> dict:
    """One row per setting: errors of the first seed's bake; with two seeds also PDIC's own noise.
    masks : :func:`bench.run.texel_masks` of the scene (computed if None)."""
    settings = bench_run.with_deviations(preset(quality, threads=1, **overrides), switches)
    masks = masks if masks is not None else bench_run.texel_masks(scene, settings.texel_samples)
    bakes = []
    for seed in seeds:
        t = time.process_time()
        bakes.append((bake(scene, replace(settings, seed=seed)), time.process_time() - t))
    result, cpu = bakes[0]
    c, s = result.stats["counters"], result.stats["seconds"]
    inside = {n: cov & masks[n][0] for n, cov in result.centre_inside.items()}
    comparable = {n: cov & masks[n][1] for n, cov in result.centre_inside.items()}
    # Texels not buried (no part inside closed geometry): a camera sees them. Inside, PDIC's texel means hold 0
    # where Cycles finds light that entered a shell through an opening (bench/cathedral_indirect.py).
    outside = {n: cov & ~result.buried[n] for n, cov in result.centre_inside.items()}
    row = dict(scene=name, quality=quality, **overrides, deviations=switches, cpu_s=cpu,
               bias=bench_run.mean_bias(result.indirect, result.centre_inside, pair),
               bias_interior=bench_run.mean_bias(result.indirect, inside, pair),
               error=bench_run.noise_corrected_error(result.indirect, result.centre_inside, pair),
               error_comparable=bench_run.noise_corrected_error(result.indirect, comparable, pair),
               error_interior=bench_run.noise_corrected_error(result.indirect, inside, pair),
               error_outside=bench_run.noise_corrected_error(result.indirect, outside, pair),
               blocks_judged_off=bench_run.blocks_off(result.indirect, result.centre_inside, pair),
               blocks_judged_off_comparable=bench_run.blocks_off(result.indirect, comparable, pair),
               blocks_judged_off_outside=bench_run.blocks_off(result.indirect, outside, pair),
               blocks_off_outside_by_fill=bench_run.blocks_off_by_fill(result.indirect, outside, pair),
               photons_stored=c.get("photons_stored"), photon_bytes=c.get("photon_bytes"),
               photons_before_control=c.get("photons_before_control"), records=c.get("records"),
               hole_records=c.get("hole_records"), stage_seconds=s)
    if len(bakes) >= 2:
        row.update(seed_split(bakes[0][0], bakes[1][0], inside, pair))
    print(json.dumps(row, default=float), flush=True)
    return row


def seed_split(first, second, covered: dict, pair) -> dict:
    """PDIC's own seed-to-seed noise and its systematic error (both noises removed), relative to
    the reference mean, over ``covered`` texels, from two bakes that differ only in the seed.

    With x1, x2 the bakes and r1, r2 the reference pair: E(x1 - x2)^2 / 2 is PDIC's variance v;
    E((x1 + x2) / 2 - (r1 + r2) / 2)^2 = bias^2 + v / 2 + (reference noise)^2 / 2.
    """
    a, b = pair
    names = [n for n in a["images"] if n in covered]
    def cat(images):
        return np.concatenate([images[n][a["coverage"][n] & b["coverage"][n] & covered[n]
                                         & first.centre_inside[n] & second.centre_inside[n]].ravel() for n in names])
    x1, x2 = cat(first.indirect), cat(second.indirect)
    r1, r2 = cat(a["images"]), cat(b["images"])
    mean = max(0.5 * float((r1 + r2).mean()), 1e-30)
    variance = float(np.mean((x1 - x2) ** 2)) / 2.0
    squared = float(np.mean((0.5 * (x1 + x2) - 0.5 * (r1 + r2)) ** 2)) - variance / 2.0 - float(np.mean((r1 - r2) ** 2)) / 4.0
    return dict(pdic_seed_noise=np.sqrt(variance) / mean, error_systematic=np.sqrt(max(squared, 0.0)) / mean)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="cornell,occluded,sponza")
    ap.add_argument("--quality", default="FINAL")
    ap.add_argument("--bounces", default="6,64")
    ap.add_argument("--density-control", default="0")
    ap.add_argument("--photons", type=int, default=None)
    ap.add_argument("--seeds", default="0", help="seeds baked per row; two split the interior error into "
                    "PDIC's own seed-to-seed noise and its systematic error")
    ap.add_argument("--figure5", action="store_true")
    ap.add_argument("--tag", default="", help="references baked with bench/converged_references.py --tag "
                    "(e.g. _b52; for Blender 5.2's Cycles also --footprint-side 1, as the add-on sets it)")
    ap.add_argument("--deviations", default="", help="Deviations switches, e.g. path_visibility=1")
    ap.add_argument("--set", default="", help="BakeSettings overrides, e.g. r_min_texels=3,a=0.5")
    ap.add_argument("--footprint-side", type=float, default=None,
                    help="direct_footprint_side (texels): 1 for Blender 5.2's Cycles, as the add-on sets it")
    ap.add_argument("--kernel-coverage", choices=("default", "on", "off"), default="default",
                    help="force E_k's surface-coverage kernel on or off at both qualities")
    args = ap.parse_args(argv)
    if args.kernel_coverage != "default":
        from pdic.core import pipeline
        chosen, on = pipeline.cache_parameters, args.kernel_coverage == "on"
        pipeline.cache_parameters = lambda *a: replace(chosen(*a), kernel_coverage=on)
    for name in args.scenes.split(","):
        scene, pair, noise = load(name, args.tag)
        print(f"# {name}: reference noise {noise:.4f}", flush=True)
        photons = args.photons or preset(args.quality).photons
        if args.figure5:
            out = bench_run.figure5(name, scene, photons, int(args.bounces.split(",")[-1]), {}, None, pair)
            out.pop("_images", None)
            continue
        masks = bench_run.texel_masks(scene, preset(args.quality).texel_samples)
        for bounces in (int(b) for b in args.bounces.split(",")):
            for n in (int(v) for v in args.density_control.split(",")):
                side = {} if args.footprint_side is None else dict(direct_footprint_side=args.footprint_side)
                side.update(bench_run.overrides(args.set))
                measure(name, scene, pair, args.quality,
                        dict(max_bounces=bounces, density_control=n, photons=photons, **side), args.deviations, masks,
                        [int(v) for v in args.seeds.split(",")])


if __name__ == "__main__":
    main()
