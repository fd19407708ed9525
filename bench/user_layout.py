"""A light map in the user's own layout: Sponza baked into Blender's Lightmap Pack UVs and into PDIC's unwrap.

    .venv/bin/python bench/user_layout.py [--texel-density 8] [--seeds 0,1] [--camera-spp 256]

An object's Light-Map UVs (docs/settings.md) make PDIC bake into a layout the user made. The layout
changes which texels hold the light, not the light: both bakes, read from the same cameras, should be
as close to Cycles as each other. Sponza (one object, ``../shared/scenes/sponza``, two point lights in
the atrium) gets a UV map from Blender's own *UV > Lightmap Pack* (every face an island, 0.2 margin);
PDIC Final bakes it at ``--texel-density`` through the add-on's job, once into that layout and once
into its own xatlas unwrap, for each seed. Each map is read bilinearly at the points two cameras see
(bench/camera_competitors.py's Sponza views, 480 x 270, E / pi) and compared with a pair of Cycles
camera renders of E / pi there (32 bounces, no clamping, its noise subtracted): relative RMSE per pixel
and over 4x4 pixel blocks, and the mean ratio; then the bakes with each other. Prints a table; about
25 minutes on 2 cores (Cycles' four renders take 7).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import pdic_bootstrap  # noqa: E402

pdic_bootstrap.load()
import bpy  # noqa: E402

from pdic import pdic_addon  # noqa: E402
from pdic.bench import competitors  # noqa: E402
from pdic.bench.bake_vs_camera import white_for_camera, world_offset  # noqa: E402
from pdic.bench.camera_competitors import (REFERENCE_SEEDS, VIEWS, blender_camera, camera_reference,  # noqa: E402
                                           core_camera, lightmap_view, seen)
from pdic.bench.competitors import join  # noqa: E402
from pdic.core.rays import RayCaster  # noqa: E402
from pdic.core.settings import preset  # noqa: E402
from pdic.pdic_addon.job import BakeJob  # noqa: E402
from pdic.bench.scenes import load_sponza  # noqa: E402

SHAPE = (270, 480)
LAYOUT = "Lightmap"


def lightmap_pack(obj) -> None:
    """Give ``obj`` a UV map LAYOUT made by Blender's Lightmap Pack (its own UV maps untouched)."""
    obj.data.uv_layers.active = obj.data.uv_layers.new(name=LAYOUT)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    bpy.ops.uv.lightmap_pack(PREF_CONTEXT="ALL_FACES", PREF_MARGIN_DIV=0.2)
    bpy.ops.object.mode_set(mode="OBJECT")


def bake_seen(obj, own: bool, density: float, seed: int) -> tuple[np.ndarray, dict]:
    """(views side by side (H, 2W, 3) E / pi, facts) of a Final bake into LAYOUT (``own``) or xatlas's."""
    obj.pdic.uv_map = LAYOUT if own else ""
    with tempfile.TemporaryDirectory() as folder:
        job = BakeJob(bpy.context, preset("FINAL", texel_density=density, seed=seed), objects=[obj],
                      output_folder=str(Path(folder) / "maps"), cache_dir=Path(folder) / "unwrap")
        job.bake_cache_dir = Path(folder) / "bake_cache"
        start = time.perf_counter()
        job.run()
        wall = time.perf_counter() - start
        bpy.ops.pdic.clear()  # the file as it was: the next bake and Cycles' renders see the user's materials
    scene, image = job.extraction.scene, job.result.lightmaps[obj.name]
    caster, offset = RayCaster(scene.geometry.positions, scene.extent), world_offset(scene)
    views = []
    for eye, look, half_width in VIEWS["sponza16"]:
        camera = core_camera(blender_camera(eye, look, half_width, SHAPE[1], SHAPE[0]), offset, half_width,
                             SHAPE[1], SHAPE[0])
        views.append(seen(image, lightmap_view(scene, caster, camera, SHAPE[1], SHAPE[0]), SHAPE))
    return np.concatenate(views, axis=1), dict(wall=wall, size=image.shape[0], **job.unwraps[obj.name])


def reference_pair(spp: int) -> tuple:
    """Cycles' E / pi at each pixel's point, seeds REFERENCE_SEEDS, views side by side."""
    for material in bpy.data.materials:
        if material.node_tree is not None:
            white_for_camera(material)
    renders = []
    with tempfile.TemporaryDirectory() as folder:
        for eye, look, half_width in VIEWS["sponza16"]:
            blender_camera(eye, look, half_width, SHAPE[1], SHAPE[0])
            renders.append([camera_reference(spp, s, Path(folder)) for s in REFERENCE_SEEDS])
    return tuple(np.concatenate([r[k] for r in renders], axis=1) for k in (0, 1))


def block_difference(a: np.ndarray, b: np.ndarray, mask: np.ndarray, block: int) -> float:
    """Relative RMS difference of two bakes' block means (no noise subtracted: both are PDIC's)."""
    (x, blocks), (y, _) = (competitors.block_means(v, mask, block) for v in (a, b))
    return float(np.sqrt(np.mean((x[blocks] - y[blocks]) ** 2)) / np.mean(y[blocks]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--texel-density", type=float, default=8.0)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--camera-spp", type=int, default=256)
    args = ap.parse_args()
    pdic_addon.register()
    obj = join(load_sponza())
    lightmap_pack(obj)
    seen_by, facts = {}, {}
    for seed in (int(s) for s in args.seeds.split(",")):
        for own in (True, False):
            name = f"{'Lightmap Pack' if own else 'PDIC unwrap'}, seed {seed}"
            seen_by[name], facts[name] = bake_seen(obj, own, args.texel_density, seed)
            print(f"{name}: {facts[name]}", flush=True)
    pair = reference_pair(args.camera_spp)
    mask = np.logical_and.reduce([v.sum(axis=-1) > 0 for v in seen_by.values()])
    print(f"\n{int(mask.sum()):,} pixels seen by every bake; Cycles {args.camera_spp} spp x 2")
    print("| layout, seed | map | bake s | per pixel | 4x4 blocks | mean ratio |\n| --- | --- | --- | --- | --- | --- |")
    for name, image in seen_by.items():
        e = competitors.errors(image, pair, mask, block=4)
        print(f"| {name} | {facts[name]['size']}^2 | {facts[name]['wall']:.0f} | {100 * e['texel']:.2f} % | "
              f"{100 * e['block']:.2f} % | {e['mean_ratio']:.4f} |")
    names = list(seen_by)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            print(f"{a} vs {b}: per pixel {100 * block_difference(seen_by[a], seen_by[b], mask, 1):.2f} %, "
                  f"4x4 {100 * block_difference(seen_by[a], seen_by[b], mask, 4):.2f} %")


if __name__ == "__main__":
    main()
