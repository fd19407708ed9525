"""Is a Cycles bake a fair reference? Its indirect light against a Cycles camera render of the same points.

    .venv/bin/python bench/bake_vs_camera.py [--scene sponza16] [--bake-spp 16] [--camera-spp 16]

PDIC's light maps are judged against Cycles Diffuse Indirect bakes (no Color) of its own UVs
(bench/competitors.py). This checks those bakes against what Cycles renders from a camera, on
the texels a camera straight above sees: up-facing texels whose ray straight up leaves the scene
(Sponza: its atrium floor and its roofs). Every material's surface is mixed, for camera rays only, into a white
Diffuse BSDF (Light Path "Is Camera Ray"), so an orthographic camera's pixel holds E / pi at the
point it sees while every bounce still meets the scene's own materials; the indirect part is a
render at the bench's 32 diffuse bounces minus one at 0. Each texel takes the mean of the 2x2
pixels nearest its centre (``--pixel`` metres wide: half a texel at Sponza's 16 texels/m). Prints
the bake's and the camera's indirect light summed per channel over those texels, and their ratio;
with ``--pdic`` (an npz holding PDIC's indirect map under the object's name, e.g. a saved
``BakeResult.indirect``) PDIC's too. The scene's extraction only translates it (its lights give the
offset); the camera sees the topmost surface over each texel, which the upward ray proved is it.

Measured (session 23, Sponza 16 texels/m, the defaults: a 16-spp bake pair, a 16-spp camera, 3 cm
pixels; 64,761 texels, the atrium floor and the roofs; 105 s): relative R/G/B of the camera
1.248 / 1 / 0.791 and of the bake the same, bake / camera 0.997 / 0.998 / 0.998; PDIC Final (seed 0)
0.981 / 0.983 / 0.986 of the camera. On the atrium floor alone against the competitors' 128-spp pair
(12,462 texels) the bake is 1.003 of the camera in each channel. So the bake is not less warm than
the camera's view: the Sponza figures of an earlier PDIC (a bake at 1.12 / 1.00 / 0.88, PDIC's map
and the camera at 1.22-1.23 / 0.99 / 0.78) are not reproduced, and over all interior texels the
bake and PDIC's map have the same balance (1.320 / 1 / 0.746 and 1.318 / 1 / 0.748).
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
from pdic.core.rays import RayCaster  # noqa: E402

SKY_MARGIN = 0.5
"""Metres of the camera's view beyond the outermost texel judged."""


def sky_texels(scene, position, normal, centre) -> np.ndarray:
    """Flat indices of texels facing up (normal z > 0.99) whose ray straight up hits nothing."""
    up = centre & (normal[..., 2] > 0.99)
    index = np.flatnonzero(up.ravel())
    p = position.reshape(-1, 3)[index]
    caster = RayCaster(scene.geometry.positions)
    hits = caster.intersect(p + [0.0, 0.0, 1e-3], np.tile([0.0, 0.0, 1.0], (len(p), 1)), unit=True)
    return index[~hits.hit]


def white_for_camera(material) -> None:
    """Mix the material's surface, for camera rays only, into a white Diffuse BSDF."""
    tree = material.node_tree
    outputs = [n for n in tree.nodes if n.type == "OUTPUT_MATERIAL" and n.is_active_output]
    if not outputs or not outputs[0].inputs["Surface"].is_linked:
        return
    surface = outputs[0].inputs["Surface"]
    source = surface.links[0].from_socket
    path, white, mix = (tree.nodes.new(kind) for kind in
                        ("ShaderNodeLightPath", "ShaderNodeBsdfDiffuse", "ShaderNodeMixShader"))
    white.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    tree.links.new(path.outputs["Is Camera Ray"], mix.inputs[0])
    tree.links.new(source, mix.inputs[1])
    tree.links.new(white.outputs["BSDF"], mix.inputs[2])
    tree.links.new(mix.outputs["Shader"], surface)


def render(path: Path, diffuse_bounces: int) -> np.ndarray:
    """(rows, cols, 3) float32 Combined of the scene's camera, row 0 at the top."""
    scene = bpy.context.scene
    scene.cycles.diffuse_bounces = diffuse_bounces
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    image = bpy.data.images.load(str(path))
    width, height = image.size
    pixels = np.empty(width * height * 4, np.float32)
    image.pixels.foreach_get(pixels)
    bpy.data.images.remove(image)
    return pixels.reshape(height, width, 4)[::-1, :, :3]


def camera_settings(spp: int, seed: int | None = None) -> None:
    """Cycles on the CPU at ``spp`` samples per pixel, no adaptive sampling, denoising or clamping, the
    bench's bounces, a pixel filter of 0.01 (a pixel is its own area, in effect its centre's point),
    32-bit EXR output; ``seed`` (None: the scene's as it is) fixed, not animated, no time limit."""
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    cycles = scene.cycles
    cycles.device, cycles.samples, cycles.use_adaptive_sampling, cycles.use_denoising = "CPU", spp, False, False
    if seed is not None:
        cycles.seed, cycles.use_animated_seed, cycles.time_limit = seed, False, 0.0
    cycles.sample_clamp_direct = cycles.sample_clamp_indirect = 0.0
    cycles.max_bounces = competitors.CYCLES_BOUNCES
    cycles.filter_width = 0.01
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"


def world_offset(scene) -> np.ndarray:
    """(3,) world minus scene-local position: the extraction only translates (its lights give it)."""
    lights = {o.name: np.array(o.location) for o in bpy.data.objects if o.type == "LIGHT"}
    return lights[scene.lights[0].name] - scene.lights[0].position


def camera_indirect(points: np.ndarray, pixel: float, spp: int, folder: Path) -> np.ndarray:
    """(n, 3) indirect E / pi at world points (n, 3) on up-facing floor, from an orthographic camera above."""
    scene = bpy.context.scene
    lo, hi = points[:, :2].min(axis=0) - SKY_MARGIN, points[:, :2].max(axis=0) + SKY_MARGIN
    cols, rows = (int(np.ceil(v)) for v in (hi - lo) / pixel)
    data = bpy.data.cameras.new("PDIC_BenchTop")
    data.type = "ORTHO"
    data.ortho_scale = max(cols, rows) * pixel
    camera = bpy.data.objects.new("PDIC_BenchTop", data)
    camera.location = (*(0.5 * (lo + hi)), points[:, 2].max() + 100.0)
    scene.collection.objects.link(camera)
    scene.camera = camera
    camera_settings(spp)
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = cols, rows, 100
    for material in bpy.data.materials:
        if material.node_tree is not None:
            white_for_camera(material)
    full = render(folder / "full.exr", competitors.CYCLES_BOUNCES)
    indirect = full - render(folder / "direct.exr", 0)
    # Pixel (r, c) spans [c, c + 1) x [r, r + 1) in (u, v), u along x and v down from the top edge:
    # the 2x2 pixels whose centres lie nearest a point are k and k + 1 from k = floor(u - 0.5).
    centre = 0.5 * (lo + hi)
    u = (points[:, 0] - centre[0]) / pixel + 0.5 * cols
    v = (centre[1] - points[:, 1]) / pixel + 0.5 * rows
    col = np.clip(np.floor(u - 0.5).astype(int), 0, cols - 2)
    row = np.clip(np.floor(v - 0.5).astype(int), 0, rows - 2)
    return sum(indirect[row + dr, col + dc] for dr in (0, 1) for dc in (0, 1)) / 4.0


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="sponza16", help="a bench/competitors.py scene")
    ap.add_argument("--bake-spp", type=int, default=16)
    ap.add_argument("--camera-spp", type=int, default=16)
    ap.add_argument("--pixel", type=float, default=0.03, help="camera pixel width, metres (Sponza 16/m: half a texel)")
    ap.add_argument("--pdic", default="", help="an npz holding PDIC's indirect map under the object's name")
    ap.add_argument("--out", default="/tmp/pdic_bake_vs_camera")
    args = ap.parse_args(argv)
    pdic_addon.register()
    spec = competitors.SCENES[args.scene]
    work = Path(args.out) / args.scene
    obj, scene = competitors.load_scene(spec, work)
    position, normal, centre = competitors.texel_geometry(scene)
    height, width = centre.shape
    index = sky_texels(scene, position, normal, centre)
    points = position.reshape(-1, 3)[index] + world_offset(scene)
    rows, cols = np.unravel_index(index, (height, width))
    t = time.perf_counter()
    pair = competitors.reference_pair(obj, (width, height), competitors.PASS_SETS["indirect"], args.bake_spp,
                                      work / "references")
    bake = (0.5 * (pair[0] + pair[1]))[rows, cols, :3]
    bake_s = time.perf_counter() - t
    t = time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:
        camera = camera_indirect(points, args.pixel, args.camera_spp, Path(folder))
    camera_s = time.perf_counter() - t
    values = {"camera": camera, "bake": bake}
    if args.pdic:
        with np.load(args.pdic) as f:
            values["PDIC"] = f[obj.name][rows, cols, :3]
    print(f"{args.scene}: {len(index):,} up-facing texels under open sky; bake {args.bake_spp} spp x 2 "
          f"({bake_s:.0f} s), camera {args.camera_spp} spp ({camera_s:.0f} s)")
    for name, v in values.items():
        s = v.sum(axis=0)
        print(f"  {name:6s} relative R/G/B {np.round(s / s[1], 3)}; / camera {np.round(s / camera.sum(axis=0), 3)}")


if __name__ == "__main__":
    main()
