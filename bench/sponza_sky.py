"""Sponza under an open sky: PDIC Final's direct light, the sky through the records or the texels' own rays,
against Cycles texel by texel.

    .venv/bin/python bench/sponza_sky.py [--density 4] [--spp 128] [--out DIR]

Sponza (``../shared/scenes/sponza``) as one object, as bench/competitors.py loads it, with its lamps
removed and a uniform white world of strength 1: the atrium is open to the sky, the arcades see it
past columns and arches. PDIC bakes Final twice on the core scene, with sky gathering (the default,
docs/DEVIATIONS.md) and without it (``sky_gathering=False``: 16 shadow rays per texel sample); Cycles
bakes Diffuse Direct (no Color, adaptive sampling off) into the same ``PDIC_Lightmap`` UVs with seeds
1 and 2. Prints the noise-corrected relative RMSE per texel and on 8x8 blocks over the texels Cycles
lights and over interior texels (``bench.run.interior_texels``: whole, on no face duplicated in
place), the mean ratio, and how much light each bake puts on texels Cycles leaves black.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / "tests"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))
import pdic_bootstrap  # noqa: E402

pdic_bootstrap.load()
import bpy  # noqa: E402

import cycles_reference as cr  # noqa: E402
from bench.competitors import SceneSpec, errors, load_scene  # noqa: E402
from bench.run import interior_texels  # noqa: E402
from test_direct_vs_cycles import _world  # noqa: E402
from pdic import pdic_addon  # noqa: E402
from pdic.core.pipeline import bake  # noqa: E402
from pdic.core.scene import World  # noqa: E402
from pdic.core.settings import Deviations, preset  # noqa: E402
from pdic.pdic_addon.uvmaps import LIGHTMAP_UV  # noqa: E402


def open_sky(scene):
    """The Blender file and the core scene without lamps, under a white world of strength 1."""
    for light in [o for o in bpy.data.objects if o.type == "LIGHT"]:
        bpy.data.objects.remove(light)
    _world(bpy, (1.0, 1.0, 1.0), 1.0)
    return replace(scene, lights=(), world=World(np.ones(3)))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--density", type=float, default=4.0, help="texels per metre")
    ap.add_argument("--spp", type=int, default=128, help="Cycles samples of each reference bake")
    ap.add_argument("--out", default="/tmp/pdic_sponza_sky")
    args = ap.parse_args(argv)
    pdic_addon.register()
    spec = SceneSpec(f"Sponza, {args.density:g} texels/m", "sponza", 0, args.density, (), args.spp, (0, 0, 0))
    obj, scene = load_scene(spec, Path(args.out))
    scene = open_sky(scene)
    name = scene.targets[0].name
    bakes = {}
    for label, on in (("sky through the records", True), ("texels' own sky rays", False)):
        cpu = time.process_time()
        bakes[label] = (bake(scene, preset("FINAL", deviations=Deviations(sky_gathering=on))), time.process_time() - cpu)
    H, W = next(iter(bakes.values()))[0].direct[name].shape[:2]
    pair = tuple(cr.cycles_bake_full([obj], LIGHTMAP_UV, W, H, {"DIRECT"}, args.spp, seed=seed, diffuse_bounces=32,
                                     clamp_indirect=0.0).images[obj.name][..., :3] for seed in (1, 2))
    centre = next(iter(bakes.values()))[0].centre_inside[name]
    lit = ((pair[0].sum(axis=2) > 0) | (pair[1].sum(axis=2) > 0)) & centre
    interior = interior_texels(scene, 2)[name]
    mean = 0.5 * (pair[0] + pair[1])
    noise = np.sqrt(np.mean((pair[0] - pair[1])[lit] ** 2) / 2) / float(mean[lit].mean())
    print(f"{spec.label}: {W}x{H}, {int(lit.sum()):,} texels Cycles lights, its noise per texel {noise:.2%}")
    black = centre & (mean.sum(axis=2) == 0)
    for label, (result, cpu) in bakes.items():
        image = result.direct[name]
        err = errors(image, pair, lit, interior)
        total = float(image[centre].sum())
        print(f"{label:24s} {cpu:6.1f} CPU s; per texel {err['texel']:.2%} / 8x8 {err['block']:.2%}, interior "
              f"{err['texel_interior']:.2%} / {err['block_interior']:.2%}, mean {err['mean_ratio']:.4f}; light on texels "
              f"Cycles leaves black: {image[black].sum() / total:.2%} ({image[black & interior].sum() / total:.2%} "
              f"on interior texels)")


if __name__ == "__main__":
    main()
