"""Crops of the Cornell box's indirect light (Final, 256^2 per object) against the converged reference.

    .venv/bin/python bench/blotch_crops.py [--out bench/plots/blotch_crops_cornell.png]

Rows: the floor and the back wall. Columns: the converged 64-bounce Cycles pair's mean (64^2,
2 x 2048 spp), PDIC Final with one gather per record (the adaptive-gathering deviation off: the
blotches before it, docs/DEVIATIONS.md), PDIC Final at the defaults, and both PDIC maps' 8x8-block
relative difference to the reference (blue darker, red brighter, +-20 %). Bench-only: matplotlib.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
from bench import run as bench_run  # noqa: E402  (loads pdic and bpy)
from bench.cornell_compare import CONVERGED  # noqa: E402

import bpy  # noqa: E402
from pdic.core.pipeline import bake  # noqa: E402
from pdic.core.settings import preset  # noqa: E402
from pdic.pdic_addon.extract import extract_scene  # noqa: E402

RES = 256
OBJECTS = ("Floor", "BackWall")
VARIANTS = (("one gather per record", "adaptive_gathering=0"), ("defaults", ""))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "bench" / "plots" / "blotch_crops_cornell.png"))
    args = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "sample_blends" / "cornell_point.blend"))
    objects = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    ex = extract_scene(bpy.context.evaluated_depsgraph_get(), objects, "LightMap", {o.name: (RES, RES) for o in objects})
    ref = np.load(CONVERGED)
    maps = {label: bake(ex.scene, bench_run.with_deviations(preset("FINAL"), switches)) for label, switches in VARIANTS}
    fig, axes = plt.subplots(len(OBJECTS), 1 + 2 * len(VARIANTS), figsize=(3 * (1 + 2 * len(VARIANTS)), 3 * len(OBJECTS)))
    for row, name in enumerate(OBJECTS):
        cov = ref[f"cov_{name}"]
        reference = 0.5 * (ref[f"a_{name}"] + ref[f"b_{name}"])
        scale = np.percentile(reference[cov].mean(-1), 99)
        axes[row, 0].imshow(np.clip(reference / scale, 0, 1)[::-1], interpolation="nearest")
        axes[row, 0].set_title(f"{name}: Cycles 64 bounces")
        ref_blocks = bench_run.block_average(reference, cov, 2).mean(-1)
        for i, (label, _) in enumerate(VARIANTS):
            result = maps[label]
            image = result.indirect[name]
            axes[row, 1 + i].imshow(np.clip(image / scale, 0, 1)[::-1], interpolation="nearest")
            axes[row, 1 + i].set_title(f"PDIC Final, {label}", fontsize=8)
            blocks = bench_run.block_average(image, result.centre_inside[name], 8).mean(-1)
            diff = np.where(ref_blocks > 0, blocks / np.maximum(ref_blocks, 1e-9) - 1.0, np.nan)
            axes[row, 1 + len(VARIANTS) + i].imshow(diff[::-1], cmap="coolwarm", vmin=-0.2, vmax=0.2,
                                                    interpolation="nearest")
            axes[row, 1 + len(VARIANTS) + i].set_title(f"8x8 blocks vs Cycles, {label}", fontsize=8)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(args.out, dpi=80)
    print("wrote", args.out)


if __name__ == "__main__":
    main()
