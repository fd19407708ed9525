"""Cycles + OIDN against PDIC as a camera sees their light maps.

    .venv/bin/python bench/camera_competitors.py [--scene sponza16|sponza2048|occluded|cornell256] [--ladder 4,16,64]
        [--camera-spp 256]

(OIDN is a bench dependency: ``.venv/bin/python -m pip install -r requirements-bench.txt``, as
tools/bench.sh does.) Scene, UVs and unwrap cache are bench/competitors.py's.

bench/competitors.py compares light maps texel by texel with a Cycles bake of the same UVs. At a
chart's edge the two bakers mean different things by a texel (Cycles jitters its sample past the
triangle, PDIC averages its samples on it), and there the bake is its own reference. A user sees
neither: a renderer reads the map bilinearly at the points a camera sees. So this renders each
baker's map from cameras inside the scene (one primary ray per pixel centre, the map read
bilinearly at the hit's light-map UV, E / pi: white albedo) and compares it with what Cycles renders
from the same cameras when every surface is white for camera rays (bench/bake_vs_camera.py's
``white_for_camera``: a pixel holds E / pi at the point it sees, every bounce meets the scene's
own materials; 32 bounces, no clamping, pixel filter 0.01 so a pixel is its centre's point). Two
such renders with seeds 1 and 2 are the reference, their noise subtracted (bench/run.py
``noise_corrected_error``). Pixels that see a back face or nothing are left out (a light map holds
front faces). Errors: relative RMSE per pixel and on 4x4-pixel block means (the issue's measure);
CPU seconds as in bench/competitors.py, and Cycles + OIDN's CPU seconds at PDIC Final's error,
log-log interpolated on the ladder (``competitors.cycles_cpu_at_error``; "not reached" where that
needs more than EXTRAPOLATION_LIMIT x the dearest rung). Writes ``results/competitors/<scene>/
camera_competitors.json``, the rendered views (``camera_*.npy``) and ``results/camera_crops_<scene>.png``
(reference, PDIC Final, Cycles + OIDN RTLightmap at the ladder's top; their errors below).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import pdic_bootstrap  # noqa: E402

pdic_bootstrap.load()
import bpy  # noqa: E402

from pdic import pdic_addon  # noqa: E402
from pdic.bench import competitors  # noqa: E402
from pdic.bench.bake_vs_camera import camera_settings, render, white_for_camera, world_offset  # noqa: E402
from pdic.core.camera_render import Camera, bilinear, lightmap_uvs  # noqa: E402
from pdic.core.rays import RayCaster  # noqa: E402

VIEWS = {
    # world metres: (eye, look-at, tan of half the horizontal field of view)
    # into the box through its open side
    "cornell256": [((0.0, -1.0, 0.3), (0.0, 0.28, 0.2), 0.36)],
    # room 2, lit only through doorways, across its columns; room 3's stair from under its gallery
    "occluded": [((11.6, 0.4, 1.6), (7.0, 4.5, 1.0), 0.75), ((12.4, 5.6, 1.7), (17.0, 1.5, 1.8), 0.75)],
    # along the atrium from its west end, and into the south arcade
    "sponza16": [((-12.0, 0.0, 1.7), (8.0, 2.5, 2.5), 0.75), ((3.0, 1.0, 1.6), (9.0, -5.5, 1.5), 0.75)],
}
VIEWS["sponza2048"] = VIEWS["sponza16"]
BLOCK = 4
"""Pixels per side of the blocks whose means are compared (issue #12's camera measure)."""
REFERENCE_SEEDS = (1, 2)
EXTRAPOLATION_LIMIT = 4.0
"""Equal-error times past this multiple of the ladder's dearest rung are reported as not reached."""
CROPS = {"sponza16": (10, 190, 680, 920), "sponza2048": (10, 190, 680, 920), "occluded": (40, 230, 100, 400),
         "cornell256": (60, 270, 100, 380)}
"""(row0, row1, col0, col1) of the views side by side that the crop sheet shows."""


def blender_camera(eye, target, half_width: float, width: int, height: int):
    """Make the scene's camera look from ``eye`` at ``target`` (world) with tan(half the horizontal
    field of view) ``half_width``; returns the bpy object."""
    from mathutils import Vector

    scene = bpy.context.scene
    data = bpy.data.cameras.new("PDIC_BenchView")
    data.sensor_fit, data.sensor_width = "HORIZONTAL", 36.0
    data.lens = 18.0 / half_width
    data.clip_start, data.clip_end = 0.01, 1000.0
    camera = bpy.data.objects.new("PDIC_BenchView", data)
    scene.collection.objects.link(camera)
    camera.location = eye
    camera.rotation_euler = (Vector(target) - Vector(eye)).to_track_quat("-Z", "Y").to_euler()
    bpy.context.view_layer.update()
    scene.camera = camera
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = width, height, 100
    return camera


def core_camera(camera, offset: np.ndarray, half_width: float, width: int, height: int) -> Camera:
    """The same pinhole in the extraction's scene-local space (it only translates: ``offset``)."""
    m = np.array(camera.matrix_world)
    return Camera(position=m[:3, 3] - offset, rotation=m[:3, :3], half_width=half_width,
                  half_height=half_width * height / width)


def camera_reference(spp: int, seed: int, folder: Path) -> np.ndarray:
    """(rows, cols, 3) Cycles' E / pi at each pixel's point (materials already white for camera rays);
    pixel filter 0.01: a pixel is the point at its centre, as the light-map renderer's ray."""
    camera_settings(spp, seed)
    return render(folder / f"camera_{seed}.exr", competitors.CYCLES_BOUNCES)


def lightmap_view(scene, caster: RayCaster, camera: Camera, width: int, height: int):
    """Where each pixel reads the one target's light map: (uv (n, 2), pixel index (n,)) of the pixels
    whose centre ray hits a front face of the target."""
    origins, directions = camera.rays(width, height)
    hits = caster.intersect(origins, directions)
    g, target = scene.geometry, scene.targets[0]
    hit = np.flatnonzero(hits.hit)
    tri = hits.triangle[hit]
    front = np.einsum("ij,ij->i", caster.face_normals[tri], directions[hit]) < 0
    keep = front & (g.target[tri] == 0)
    hit, tri = hit[keep], tri[keep]
    u, v = hits.barycentric[hit, 0:1], hits.barycentric[hit, 1:2]
    return lightmap_uvs(target, g.count, tri, np.stack([1.0 - u - v, u, v], axis=1)), hit


def seen(image: np.ndarray, view, shape) -> np.ndarray:
    """(rows, cols, 3) the light map ``image`` read bilinearly where the camera sees it, 0 elsewhere."""
    uv, pixel = view
    out = np.zeros((shape[0] * shape[1], 3), np.float32)
    out[pixel] = bilinear(np.asarray(image)[..., :3], uv)
    return out.reshape(shape[0], shape[1], 3)


def bake_maps(scene, obj, ladder, normal) -> dict:
    """Method name -> (light map (H, W, >=3) E / pi, Cycles spp or None, wall s, CPU s): PDIC Final, then
    Cycles at each ``ladder`` rung raw and through each OIDN filter (bench/competitors.py's settings)."""
    from pdic.core.pipeline import bake
    from pdic.core.settings import preset

    target = scene.targets[0]
    size = (target.width, target.height)
    result, wall, cpu = competitors.clocked(bake, scene, preset("FINAL"))
    maps = {"PDIC Final": (result.lightmaps[target.name], None, wall, cpu)}
    competitors.warm_up_denoisers()
    for spp in ladder:
        b = competitors.cycles_bake(obj, size, competitors.PASS_SETS["all"], spp, competitors.LADDER_SEED)
        maps[f"Cycles {spp}"] = (b["image"], spp, b["wall"], b["cpu"])
        for mode in competitors.DENOISERS:
            out, w, c = competitors.clocked(competitors.denoise, b["image"], mode, normal)
            maps[f"Cycles + OIDN {mode} {spp}"] = (out, spp, b["wall"] + w, b["cpu"] + c)
    return maps


def camera_views(scene, offset: np.ndarray, views: list, shape: tuple, spp: int) -> tuple[list, list]:
    """(each view's :func:`lightmap_view`, each view's reference pair of Cycles renders). Call after every
    bake: the materials turn white for camera rays here."""
    for material in bpy.data.materials:
        if material.node_tree is not None:
            white_for_camera(material)
    caster = RayCaster(scene.geometry.positions, scene.extent)
    height, width = shape
    looks, refs = [], []
    with tempfile.TemporaryDirectory() as folder:
        for i, (eye, look, half_width) in enumerate(views):
            camera = blender_camera(eye, look, half_width, width, height)
            looks.append(lightmap_view(scene, caster, core_camera(camera, offset, half_width, width, height),
                                       width, height))
            refs.append(tuple(camera_reference(spp, s, Path(folder)) for s in REFERENCE_SEEDS))
            print(f"view {i}: {len(looks[-1][1]):,} of {width * height:,} pixels see a front face", flush=True)
    return looks, refs


def compare(maps: dict, looks: list, refs: list, shape: tuple) -> tuple[list, dict, np.ndarray, tuple]:
    """(rows as bench/competitors.py's with kind "camera", the views side by side per method, the mask of
    pixels compared, the reference pair): all views tiled into one image, one error over their pixels."""
    def tiled(images):
        return np.concatenate(images, axis=1)

    mask = tiled([np.isin(np.arange(shape[0] * shape[1]), v[1]).reshape(shape) for v in looks])
    pair = tuple(tiled([r[k] for r in refs]) for k in (0, 1))
    rows, seen_by = [], {}
    for name, (image, spp, wall, cpu) in maps.items():
        test = seen_by[name] = tiled([seen(image, v, shape) for v in looks])
        err = competitors.errors(test, pair, mask, block=BLOCK)
        rows.append(dict(method=name if spp is None else name.rsplit(" ", 1)[0], kind="camera", spp=spp,
                         wall=wall, cpu=cpu, error_texel=err["texel"], error_block=err["block"],
                         mean_ratio=err["mean_ratio"]))
        print(f"{name:32s} CPU {cpu:7.1f} s  per pixel {100 * err['texel']:6.2f} %  {BLOCK}x{BLOCK} "
              f"{100 * err['block']:6.2f} %  mean {err['mean_ratio']:.3f}", flush=True)
    return rows, seen_by, mask, pair


def equal_error(rows: list) -> dict:
    """Key "<Cycles method>|<metric>" -> Cycles' CPU seconds at PDIC Final's error (rows[0]) and the speedup."""
    pdic, cycles_rows = rows[0], [r for r in rows if r["spp"] is not None]
    top = max(r["cpu"] for r in cycles_rows)
    out = {}
    for metric in ("texel", "block"):
        for method in sorted({r["method"] for r in cycles_rows}):
            seconds, how = competitors.cycles_cpu_at_error(cycles_rows, method, "camera", metric,
                                                           pdic[f"error_{metric}"])
            if how == "extrapolated" and seconds > EXTRAPOLATION_LIMIT * top:
                seconds, how = None, "not reached"  # a ladder levelling off says nothing that far out
            out[f"{method}|{metric}"] = dict(cpu=seconds, how=how,
                                             speedup=None if seconds is None else seconds / pdic["cpu"])
            print(f"at PDIC Final's {metric} error: {method}: "
                  + (f"{how} on the ladder" if seconds is None else f"{seconds:.1f} CPU s ({how}), "
                                                                     f"{seconds / pdic['cpu']:.2f}x PDIC's"))
    return out


def crop_sheet(path: Path, window, reference: np.ndarray, tests: list, exposure: float = -3.0) -> None:
    """Reference, then each test image, over their |error| / reference (white = 50 %), 2x enlarged."""
    from pdic.core.camera_render import tone_map, write_png

    r0, r1, c0, c1 = window
    ref = reference[r0:r1, c0:c1]

    def error(x):
        e = np.clip(np.abs(x - ref).mean(-1) / np.maximum(ref.mean(-1), 1e-3) / 0.5, 0, 1)
        return (np.repeat(e[..., None], 3, -1) * 255).astype(np.uint8)

    cut = [t[r0:r1, c0:c1] for t in tests]
    top = np.concatenate([tone_map(ref, exposure)] + [tone_map(c, exposure) for c in cut], 1)
    bottom = np.concatenate([np.zeros_like(top[:, :c1 - c0])] + [error(c) for c in cut], 1)
    write_png(path, np.concatenate([top, bottom], 0).repeat(2, 0).repeat(2, 1))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="sponza16", choices=sorted(VIEWS))
    ap.add_argument("--ladder", default="16,64", help="Cycles bake samples per texel")
    ap.add_argument("--camera-spp", type=int, default=256)
    ap.add_argument("--width", type=int, default=480)
    ap.add_argument("--height", type=int, default=270)
    ap.add_argument("--out", default=str(ROOT / "bench" / "results"))
    args = ap.parse_args(argv)
    pdic_addon.register()
    work = Path(args.out) / "competitors" / args.scene
    obj, scene = competitors.load_scene(competitors.SCENES[args.scene], work)
    competitors.set_cycles_threads(2)
    _, normal, _ = competitors.texel_geometry(scene)

    maps = bake_maps(scene, obj, [int(s) for s in args.ladder.split(",")], normal)
    shape = (args.height, args.width)
    looks, refs = camera_views(scene, world_offset(scene), VIEWS[args.scene], shape, args.camera_spp)
    rows, seen_by, mask, pair = compare(maps, looks, refs, shape)
    reference = 0.5 * (pair[0] + pair[1])
    # the reference's own noise per pixel: the pair's mean is off by half their difference's RMS
    noise = float(np.sqrt(np.mean((pair[0] - pair[1])[mask] ** 2) / 4.0) / reference[mask].mean())
    print(f"{int(mask.sum()):,} pixels; the reference's own noise per pixel {100 * noise:.2f} %")
    summary = dict(scene=args.scene, views=VIEWS[args.scene], pixels=int(mask.sum()), camera_spp=args.camera_spp,
                   reference_noise=noise, rows=rows, equal_error=equal_error(rows))
    (work / "camera_competitors.json").write_text(json.dumps(summary, indent=1))
    for name, image in seen_by.items():
        np.save(work / f"camera_{name.replace(' ', '_').replace('+', 'p')}.npy", image)
    np.save(work / "camera_reference.npy", reference)
    top = max(r["spp"] for r in rows if r["spp"] is not None)
    crop_sheet(Path(args.out) / f"camera_crops_{args.scene}.png", CROPS[args.scene], reference,
               [seen_by["PDIC Final"], seen_by[f"Cycles + OIDN RTLightmap {top}"]])


if __name__ == "__main__":
    main()
