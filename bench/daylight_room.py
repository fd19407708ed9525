"""Daylight room: sun through a window and a uniform sky, PDIC Final against Cycles, texel by texel.

    .venv/bin/python bench/daylight_room.py [--density 16] [--spp 1024] [--bounces 32] [--out DIR]
        [--direct-samples 16] [--deviations sky_gathering=0] [--set photons=2000000] [--portal] [--glass 0.8] [--competitors 16,64]
        [--layout two-windows]
        [--quality PREVIEW] [--albedo 0.85 --sun 0 --sky 0 --uplight 500]

Every other bench scene is lit by lamps inside it; an interior lit by daylight through a window is
what most architectural and game light maps hold. One mesh object (a 6 x 5 x 3 m room with 0.2 m
walls, a 2 x 1.3 m window in the south wall, a table, a 2 cm shelf), one Diffuse BSDF of albedo
ALBEDO, a sun (SUN_STRENGTH, 35 degrees up, shining in through the window) and a uniform grey world
(WORLD_STRENGTH). PDIC bakes Final at its defaults through the add-on's ``BakeJob`` at ``--density``
texels per metre; Cycles bakes Diffuse Direct and Diffuse Indirect (no Color, adaptive sampling off,
``--bounces`` diffuse bounces, sample clamping off) into the same ``PDIC_Lightmap`` UVs twice with
seeds 1 and 2, cached in ``--out``: their mean is the reference and their difference its noise,
which is subtracted (bench/competitors.py ``errors``). Prints, for the direct and the indirect light,
the noise-corrected relative RMSE per texel and on 8x8 blocks over all texels both baked and over
the room's inside (texels whose normal faces into the room from inside it), and the mean ratio.

``--competitors 16,64``: also the baker users already have, as bench/competitors.py runs it: Cycles
bakes Diffuse Direct+Indirect (seed 0, a 16-texel margin) at those samples, raw and denoised by OIDN
(RT, RTLightmap), against the sum of the two reference pairs, with PDIC Final's direct+indirect, CPU
seconds of each (PDIC's job with its unwrap; Cycles' bake call plus the denoise).
"""
from __future__ import annotations

import argparse
import hashlib
import math
import sys
import tempfile
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
from bench.scenes import boxes_mesh  # noqa: E402
from bench.competitors import (clocked, cycles_bake, denoise, errors, set_cycles_threads,  # noqa: E402
                               texel_geometry, warm_up_denoisers)
from bench.run import with_deviations, with_overrides  # noqa: E402
from test_cathedral_direct_vs_cycles import _diffuse_material  # noqa: E402
from test_direct_vs_cycles import _world  # noqa: E402
from pdic import pdic_addon  # noqa: E402
from pdic.pdic_addon import job as job_module  # noqa: E402
from pdic.pdic_addon import writeback  # noqa: E402
from pdic.pdic_addon.properties import to_settings  # noqa: E402
from pdic.pdic_addon.uvmaps import LIGHTMAP_UV  # noqa: E402

ALBEDO = 0.7
SUN_STRENGTH = 3.0
"""W/m^2 of the sun (Blender's Strength): a floor facing it straight gets E = 3."""
SUN_ELEVATION = math.radians(35.0)
WORLD_STRENGTH = 0.5
"""A uniform grey sky: E = pi x 0.5 on an open upward face."""
ROOM = (6.0, 5.0, 3.0)
WALL = 0.2
WINDOW = ((2.0, 4.0), (0.9, 2.2))
"""The window's x and z extent in the south wall (y = 0)."""
EAST_WINDOW = ((3.3, 4.5), (1.0, 2.1))
"""Layout ``two-windows``: a second window's y and z extent in the east wall (x = 6)."""
OVERHANG = ((1.5, -1.2, 2.35), (4.5, -WALL, 2.45))
"""Layout ``two-windows``: a 1 m deep slab outside over the south window (part of the room's object)."""
TWO_WINDOWS_SUN = (math.radians(30.0), math.radians(45.0))
"""Layout ``two-windows``: the sun's elevation and azimuth (from the south-east: in through both windows)."""


def boxes(layout: str = "window") -> list:
    """The room as axis-aligned boxes ((x0, y0, z0), (x1, y1, z1)): shell, window wall, table, shelf;
    layout ``two-windows`` also has the east window and the overhang outside."""
    L, W, H, t = *ROOM, WALL
    (wx0, wx1), (wz0, wz1) = WINDOW
    if layout == "two-windows":
        (ey0, ey1), (ez0, ez1) = EAST_WINDOW
        east = [((L, -t, 0), (L + t, ey0, H)), ((L, ey1, 0), (L + t, W + t, H)),
                ((L, ey0, 0), (L + t, ey1, ez0)), ((L, ey0, ez1), (L + t, ey1, H))]
        outside = [OVERHANG]
    else:
        east, outside = [((L, -t, 0), (L + t, W + t, H))], []
    shell = [((-t, -t, -t), (L + t, W + t, 0)), ((-t, -t, H), (L + t, W + t, H + t)),
             ((-t, -t, 0), (0, W + t, H)), *east, ((0, W, 0), (L, W + t, H)), *outside]
    south = [((0, -t, 0), (wx0, 0, H)), ((wx1, -t, 0), (L, 0, H)),
             ((wx0, -t, 0), (wx1, 0, wz0)), ((wx0, -t, wz1), (wx1, 0, H))]
    table = [((2.4, 2.4, 0.72), (3.6, 3.2, 0.76))] + [
        ((x, y, 0), (x + 0.05, y + 0.05, 0.72)) for x in (2.45, 3.5) for y in (2.45, 3.1)]
    shelf = [((L - 0.3, 1.5, 1.5), (L, 3.0, 1.52))]
    return shell + south + table + shelf


def build(sun_angle: float = 0.0, lamp: float = 0.0, glass: float = 0.0, uplight: float = 0.0,
          portal: bool = False, layout: str = "window") -> bpy.types.Object:
    """A factory-fresh file with the room as one object, the sun and the sky; returns the object.

    sun_angle : the sun's angular diameter, degrees (0: hard shadows). lamp : watts of a point light
    of Blender's default radius (0.1 m) hanging 0.6 m under the ceiling over the table; 0: none.
    glass : > 0 glazes the (south) window with a 1 cm pane (an object of its own, not baked) of a Principled
    BSDF of Alpha 1 - glass: each of its two faces passes ``glass`` of the light, in Cycles and PDIC.
    uplight : watts of a hard spot light 1 m above the floor aiming straight up at the ceiling (a 90-degree
    cone): a room lit mostly by light bounced off the ceiling; 0: none. portal : a Cycles light portal (an area
    light with Portal on) filling the window at the wall's inner face, facing in: Cycles' noise changes, not
    its light; PDIC sends the sun's and the sky's photons through it (deviation portal-photons); layout
    ``two-windows``: a second window in the east wall (a portal in it too), an overhang outside over the south
    window and the sun from the south-east, 30 degrees up (TWO_WINDOWS_SUN)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    _world(bpy, (1.0, 1.0, 1.0), WORLD_STRENGTH)
    mesh = boxes_mesh("Room", boxes(layout))
    mesh.materials.append(_diffuse_material(bpy, "Plaster", ALBEDO))
    ob = bpy.data.objects.new("Room", mesh)
    bpy.context.scene.collection.objects.link(ob)
    if glass > 0:
        (wx0, wx1), (wz0, wz1) = WINDOW
        pane = bpy.data.objects.new("Pane", boxes_mesh("Pane", [((wx0, -0.105, wz0), (wx1, -0.095, wz1))]))
        pane.data.materials.append(_glass_material(1.0 - glass))
        pane.pdic.bake = False
        bpy.context.scene.collection.objects.link(pane)
    if portal:
        (wx0, wx1), (wz0, wz1) = WINDOW
        # its -Z (the side it faces) into the room: +y through the south wall
        _portal("Portal", (wx1 - wx0, wz1 - wz0), (0.5 * (wx0 + wx1), 0.0, 0.5 * (wz0 + wz1)), (math.pi / 2, 0.0, 0.0))
        if layout == "two-windows":  # -x through the east wall; its local x runs along z
            (ey0, ey1), (ez0, ez1) = EAST_WINDOW
            _portal("Portal East", (ez1 - ez0, ey1 - ey0), (ROOM[0], 0.5 * (ey0 + ey1), 0.5 * (ez0 + ez1)),
                    (0.0, math.pi / 2, 0.0))
    sun = bpy.data.lights.new("Sun", "SUN")
    sun.energy = SUN_STRENGTH
    sun.angle = math.radians(sun_angle)
    sun_ob = bpy.data.objects.new("Sun", sun)
    # A sun shines along its -Z: tilted about X by 90 - elevation it points north (+y) and down; turned about
    # Z by the azimuth, north-west.
    elevation, azimuth = TWO_WINDOWS_SUN if layout == "two-windows" else (SUN_ELEVATION, 0.0)
    sun_ob.rotation_euler = (math.pi / 2 - elevation, 0.0, azimuth)
    bpy.context.scene.collection.objects.link(sun_ob)
    if lamp > 0:
        light = bpy.data.lights.new("Lamp", "POINT")
        light.energy = lamp
        light.shadow_soft_size = 0.1
        lamp_ob = bpy.data.objects.new("Lamp", light)
        lamp_ob.location = (3.0, 2.8, ROOM[2] - 0.6)
        bpy.context.scene.collection.objects.link(lamp_ob)
    if uplight > 0:
        light = bpy.data.lights.new("Uplight", "SPOT")
        light.energy = uplight
        light.shadow_soft_size = 0.0
        light.spot_size = math.radians(90.0)
        light.spot_blend = 0.2
        up_ob = bpy.data.objects.new("Uplight", light)
        up_ob.location = (3.0, 2.5, 1.0)
        up_ob.rotation_euler = (math.pi, 0.0, 0.0)  # a spot shines along its -Z: turned over, up
        bpy.context.scene.collection.objects.link(up_ob)
    bpy.context.view_layer.update()
    return ob


def _portal(name: str, size: tuple, location: tuple, rotation: tuple) -> None:
    """A rectangular Cycles light portal of ``size`` (its local x, y) linked to the scene."""
    window = bpy.data.lights.new(name, "AREA")
    window.shape, (window.size, window.size_y) = "RECTANGLE", size
    window.cycles.is_portal = True
    window_ob = bpy.data.objects.new(name, window)
    window_ob.location, window_ob.rotation_euler = location, rotation
    bpy.context.scene.collection.objects.link(window_ob)


def _glass_material(alpha: float):
    """A Principled BSDF of base ALBEDO, no specular layer, Alpha ``alpha``: light passes 1 - alpha."""
    material = bpy.data.materials.new("Glass")
    if material.node_tree is None:
        material.use_nodes = True
    principled = next(n for n in material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    principled.inputs["Base Color"].default_value = (ALBEDO, ALBEDO, ALBEDO, 1.0)
    principled.inputs["Specular IOR Level"].default_value = 0.0
    principled.inputs["Alpha"].default_value = alpha
    return material


def digest(ob) -> str:
    """8 hex digits of the room as Cycles sees it (mesh, albedo, lights): a cached reference is for it only."""
    mesh = ob.data
    co = np.empty(len(mesh.vertices) * 3, np.float64)
    mesh.vertices.foreach_get("co", co)
    h = hashlib.sha1(co.tobytes())
    lights = sorted((o.name, o.data.type, o.data.energy, getattr(o.data, "angle", 0.0),
                     getattr(o.data, "shadow_soft_size", 0.0), tuple(o.location), tuple(o.rotation_euler))
                    for o in bpy.data.objects if o.type == "LIGHT")
    panes = sorted((o.name, o.active_material.node_tree.nodes["Principled BSDF"].inputs["Alpha"].default_value)
                   for o in bpy.data.objects if o.name.startswith("Pane"))
    h.update(repr((ALBEDO, SUN_STRENGTH, SUN_ELEVATION, WORLD_STRENGTH, lights) + ((panes,) if panes else ())).encode())
    return h.hexdigest()[:8]


def inside_room(position: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(H, W) bool: texels on the room's inside surfaces (within the room's box, facing into it)."""
    lo, hi = np.zeros(3) - 1e-3, np.array(ROOM) + 1e-3
    within = np.all((position >= lo) & (position <= hi), axis=-1)
    centre = np.array(ROOM) / 2
    return within & (np.einsum("hwj,hwj->hw", centre - position, normal) > 0)


def reference(ob, W: int, H: int, passes: str, spp: int, bounces: int, folder: Path) -> tuple:
    """The seed-1 and seed-2 Cycles bakes of one pass, cached in ``folder``."""
    cached = folder / f"reference_{digest(ob)}_{passes}_{W}x{H}_{spp}spp_{bounces}b.npz"
    if cached.exists():
        with np.load(cached) as f:
            return f["C1"], f["C2"], float(f["seconds"])
    pair, seconds = [], 0.0
    for seed in (1, 2):
        t = time.perf_counter()
        ref = cr.cycles_bake_full([ob], LIGHTMAP_UV, W, H, {passes}, spp, seed=seed, diffuse_bounces=bounces,
                                  clamp_indirect=0.0)
        seconds += time.perf_counter() - t
        pair.append(ref.images[ob.name][..., :3])
    np.savez_compressed(cached, C1=pair[0], C2=pair[1], seconds=seconds)
    return pair[0], pair[1], seconds


def bake_job(args, folder: Path, **overrides):
    """PDIC at ``args.quality``, ``args.density`` texels per metre, ``args.seed``, ``args.threads`` and
    ``args.deviations`` (and ``args.set`` where the bench has it, and BakeSettings ``overrides``) through
    the add-on's BakeJob, with a fresh bake cache and the unwraps cached in ``folder``: (the job, wall
    seconds, CPU seconds, the unwrap included)."""
    props = bpy.context.scene.pdic
    props.quality = args.quality
    props.texel_density = args.density
    props.seed = args.seed
    props.image_format = "EXR_FLOAT"
    settings = with_deviations(to_settings(props, threads=args.threads), args.deviations)
    settings = replace(with_overrides(settings, getattr(args, "set", "")), **overrides)
    t, cpu = time.perf_counter(), time.process_time()
    job = job_module.BakeJob(bpy.context, settings, output_folder=str(folder / "maps"),
                             cache_dir=folder / "unwrap_cache")
    with tempfile.TemporaryDirectory() as fresh:
        job.bake_cache_dir = Path(fresh)  # a bake, not the add-on's bake cache from an earlier run
        job.run()
    return job, time.perf_counter() - t, time.process_time() - cpu


def main(argv=None):
    global ALBEDO, SUN_STRENGTH, WORLD_STRENGTH  # the scene's constants, in the references' digest too
    ap = argparse.ArgumentParser()
    ap.add_argument("--density", type=float, default=16.0, help="texels per metre")
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--bounces", type=int, default=32)
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0, help="PDIC's seed")
    ap.add_argument("--sun-angle", type=float, default=0.0, help="the sun's angular diameter, degrees")
    ap.add_argument("--lamp", type=float, default=0.0, help="watts of a soft point light over the table")
    ap.add_argument("--direct-samples", type=int, default=0, help="PDIC's Direct Samples (0: the preset's)")
    ap.add_argument("--deviations", default="", help="switches as bench/run.py's, e.g. sky_gathering=0")
    ap.add_argument("--set", default="", help="BakeSettings overrides, e.g. photons=2000000")
    ap.add_argument("--portal", action="store_true", help="a light portal in the window (PDIC's photons use it)")
    ap.add_argument("--layout", default="window", choices=("window", "two-windows"),
                    help="two-windows: an east window too, an overhang over the south one, a south-east sun")
    ap.add_argument("--glass", type=float, default=0.0, help="a pane in the window passing this share per face")
    ap.add_argument("--quality", default="FINAL", choices=("PREVIEW", "FINAL"))
    ap.add_argument("--albedo", type=float, default=ALBEDO, help="the room's grey albedo")
    ap.add_argument("--sun", type=float, default=SUN_STRENGTH, help="the sun's strength (0: no sun)")
    ap.add_argument("--sky", type=float, default=WORLD_STRENGTH, help="the sky's strength (0: a black world)")
    ap.add_argument("--uplight", type=float, default=0.0, help="watts of a spot aiming up at the ceiling")
    ap.add_argument("--competitors", default="", help="Cycles + OIDN at these samples, e.g. 16,64")
    ap.add_argument("--out", default="/tmp/pdic_daylight_room")
    args = ap.parse_args(argv)
    folder = Path(args.out)
    folder.mkdir(parents=True, exist_ok=True)
    ALBEDO, SUN_STRENGTH, WORLD_STRENGTH = args.albedo, args.sun, args.sky
    pdic_addon.register()
    ob = build(args.sun_angle, args.lamp, args.glass, args.uplight, args.portal, args.layout)
    job, wall, cpu = bake_job(args, folder, **({"direct_samples": args.direct_samples} if args.direct_samples else {}))
    result = job.result
    writeback.set_shading([ob], baked=False)  # Cycles must bake the room's own material, not the light map
    name = ob.name
    H, W = result.indirect[name].shape[:2]
    position, normal, centre = texel_geometry(job.extraction.scene)
    room = inside_room(position + job.extraction.scene.origin_world, normal)
    counters = result.stats["counters"]
    print(f"daylight room: {len(ob.data.polygons):,} faces, map {W}x{H} at {args.density:g} texels/m; PDIC {args.quality.title()} "
          f"{wall:.1f} s wall, {cpu:.1f} CPU s (unwrap included), photons emitted {counters.get('photons_emitted'):,}, "
          f"stored {counters.get('photons_stored'):,}, records {counters.get('records_total'):,}")
    for passes, image in (("DIRECT", result.direct[name]), ("INDIRECT", result.indirect[name])):
        C1, C2, seconds = reference(ob, W, H, passes, args.spp, args.bounces, folder)
        baked = (C1.sum(axis=2) > 0) | (C2.sum(axis=2) > 0)
        baked &= centre & result.centre_inside[name]
        err = errors(image, (C1, C2), baked, room)
        mean = 0.5 * (C1 + C2)
        noise = np.sqrt(np.mean((C1 - C2)[baked] ** 2) / 2) / max(float(mean[baked].mean()), 1e-30)
        inside = baked & room
        ratio_in = float(image[inside].sum() / max(mean[inside].sum(), 1e-30))
        print(f"{passes.lower():8s} Cycles {args.spp} spp x 2 ({seconds:.0f} s), its noise per texel {noise:.2%}; "
              f"all texels {err['texel']:.2%} / 8x8 {err['block']:.2%}, mean {err['mean_ratio']:.4f}; "
              f"room's inside {err['texel_interior']:.2%} / {err['block_interior']:.2%}, mean {ratio_in:.4f}")
    np.savez_compressed(folder / f"pdic_seed{args.seed}.npz", direct=result.direct[name],
                        indirect=result.indirect[name], room=room, centre=centre)
    if args.competitors:
        ladder = [int(spp) for spp in args.competitors.split(",")]
        competitors(ob, W, H, result, name, room, centre, normal, ladder, cpu, args, folder)


def competitors(ob, W: int, H: int, result, name: str, room, centre, normal, ladder: list, pdic_cpu: float, args,
                folder: Path):
    """Cycles + OIDN against PDIC Final on direct+indirect, inside the room (see the module's docstring)."""
    pairs = [reference(ob, W, H, passes, args.spp, args.bounces, folder) for passes in ("DIRECT", "INDIRECT")]
    pair = (pairs[0][0] + pairs[1][0], pairs[0][1] + pairs[1][1])
    baked = ((pair[0].sum(axis=2) > 0) | (pair[1].sum(axis=2) > 0)) & centre & result.centre_inside[name]
    rows = [(f"PDIC {args.quality.title()} (unwrap included)", result.direct[name] + result.indirect[name], pdic_cpu)]
    set_cycles_threads(2)
    warm_up_denoisers()
    for spp in ladder:
        bake = cycles_bake(ob, (W, H), frozenset({"DIRECT", "INDIRECT"}), spp, 0)
        rows.append((f"Cycles {spp} spp", bake["image"][..., :3], bake["cpu"]))
        for mode in ("RT", "RTLightmap"):
            out, _, cpu = clocked(denoise, bake["image"][..., :3], mode, normal)
            rows.append((f"Cycles {spp} spp + OIDN {mode}", out, bake["cpu"] + cpu))
    for method, image, cpu in rows:
        err = errors(image, pair, baked, room)
        print(f"{method:34s} {cpu:6.1f} CPU s; inside {err['texel_interior']:.2%} per texel, "
              f"{err['block_interior']:.2%} 8x8; all texels {err['texel']:.2%} / {err['block']:.2%}")


if __name__ == "__main__":
    main()
