"""Cornell 256^2: PDIC's direct light against Cycles' Diffuse Direct bake, texel by texel, footprint on/off.

    .venv/bin/python -m bench.cornell_direct [--res 256] [--spp 1024] [--out bench/results/cornell_direct]

The Cornell box of the competitors bench (one object, the add-on's ``PDIC_Lightmap`` UVs, point light
of radius 0). The reference is a pair of Cycles DIRECT bakes (seeds 1, 2; cached in ``--out``);
errors are noise-corrected against it (bench.competitors.errors: relative RMSE per texel and on
8x8-texel block means) on the texels both bake (:func:`bench.competitors.cycles_coverage`). ``edge`` = baked texels within 1 texel of a shadow edge (a 3x3 neighbourhood
of the reference varying by >= 10 %), ``flat`` = the others (tests/test_direct_vs_cycles.flat_mask).
PDIC bakes direct light only with threads=1; CPU s are process time of that bake, and of its direct
stage's footprint part (from the stats' stage seconds), on a loaded machine.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
import pdic_bootstrap  # noqa: E402

pdic_bootstrap.load()

from pdic import pdic_addon  # noqa: E402
from pdic.bench import competitors as comp  # noqa: E402
from pdic.core.pipeline import bake  # noqa: E402
from pdic.core.settings import Deviations, preset  # noqa: E402
from test_direct_vs_cycles import flat_mask  # noqa: E402


def pdic_direct(scene, footprint: bool):
    """PDIC direct light (H, W, 3) E/pi of the one target, CPU s of the bake, its counters."""
    import bpy

    from pdic.pdic_addon.properties import cycles_footprint_side

    settings = preset("FINAL", indirect=False, threads=1, deviations=Deviations(direct_footprint=footprint),
                      direct_footprint_side=cycles_footprint_side(bpy.app.version))
    cpu = time.process_time()
    result = bake(scene, settings)
    cpu = time.process_time() - cpu
    name = scene.targets[0].name
    return result.direct[name], result.centre_inside[name], cpu, result.stats


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "cornell_direct"))
    args = ap.parse_args(argv)
    work = Path(args.out)
    pdic_addon.register()
    spec = replace(comp.SCENES["cornell256"], resolution=args.res)
    obj, scene = comp.load_scene(spec, work)
    comp.set_cycles_threads(2)
    target = scene.targets[0]
    size = (target.width, target.height)
    _, _, centre = comp.texel_geometry(scene)
    mask = centre & comp.cycles_coverage(obj, size, work)  # texels Cycles bakes itself, not margin fills
    pair = comp.reference_pair(obj, size, frozenset({"DIRECT"}), args.spp, work)
    reference = 0.5 * (pair[0] + pair[1])
    flat = flat_mask(reference, mask)
    edge = mask & ~flat
    noise = comp._seed_noise(pair[0], pair[1], mask)
    print(f"Cornell {size[0]}x{size[1]}: {int(mask.sum())} texels baked by both (of {int(centre.sum())} centres) ({int(edge.sum())} at edges), Cycles DIRECT "
          f"{args.spp} spp pair, seed-to-seed noise per texel {noise:.2%} (of one bake)")
    for footprint in (False, True):
        image, centre, cpu, stats = pdic_direct(scene, footprint)
        counters = stats["counters"]
        row = {}
        for label, m in (("all", mask), ("edge", edge), ("flat", flat)):
            e = comp.errors(image, pair, m & centre)
            row[label] = f"{e['texel']:.2%} / {e['block']:.2%} (mean {e['mean_ratio']:.3f})"
        print(f"footprint {'on ' if footprint else 'off'}: CPU {cpu:.2f} s (direct stage "
              f"{stats.get('seconds', {}).get('direct', float('nan')):.2f} s wall), shadow rays "
              f"{counters.get('shadow_rays', 0):,} + footprint {counters.get('direct_footprint_shadow_rays', 0):,} "
              f"({counters.get('direct_footprint_texels', 0):,} texels, "
              f"{counters.get('direct_footprint_points', 0):,} points); error texel / 8x8: "
              + "; ".join(f"{k} {v}" for k, v in row.items()))


if __name__ == "__main__":
    main()
