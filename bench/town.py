"""An outdoor town under a sun and a blue sky, many objects: PDIC Final against Cycles, texel by texel.

    .venv/bin/python bench/town.py [--density 2] [--spp 256] [--bounces 32] [--seed 0] [--out DIR]
        [--quality PREVIEW] [--deviations sky_gathering=0] [--set r_min_texels=3] [--competitors 4,16,64]

Every other bench scene is an interior or one object; a game level or a city block is many objects
outdoors, lit mostly by the sky, at a scale of a hundred metres. A ground plane (a single face, as
game levels have it) and BUILDINGS box buildings on a grid of streets, each its own object and
material (grey and coloured albedos), one of them a portico (a slab on pillars, its underside lit
only indirectly), one stepped (two boxes in one object); a sun SUN_ELEVATION up (SUN_STRENGTH,
SUN_ANGLE wide) and a uniform blue world (WORLD_COLOUR x WORLD_STRENGTH). PDIC bakes every object
at ``--density`` texels per metre through the add-on's ``BakeJob``; Cycles bakes Diffuse Direct and
Diffuse Indirect (no Color, adaptive sampling off, ``--bounces`` bounces, clamping off) into the same
``PDIC_Lightmap`` UVs with seeds 1 and 2 (cached in ``--out``), the pair's noise subtracted
(bench/competitors.py ``errors``). Prints, per object kind and over all texels both bakers cover,
the error per texel and on 8x8 blocks, the mean ratio, and the share of texels one baker lights
and the other leaves black (over the texels both cover: Cycles' margin-0 coverage and PDIC's
centre-inside texels). ``--competitors``: Cycles + OIDN on direct+indirect, as
bench/daylight_room.py runs it.
"""
from __future__ import annotations

import argparse
import hashlib
import math
import sys
import time
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
from bench.competitors import (clocked, cycles_bake, denoise, errors, set_cycles_threads,  # noqa: E402
                               warm_up_denoisers)
from bench.daylight_room import bake_job  # noqa: E402
from bench.scenes import boxes_mesh  # noqa: E402
from test_cathedral_direct_vs_cycles import _diffuse_material  # noqa: E402
from test_direct_vs_cycles import _world  # noqa: E402
from pdic import pdic_addon  # noqa: E402
from pdic.pdic_addon import writeback  # noqa: E402
from pdic.pdic_addon.uvmaps import LIGHTMAP_UV  # noqa: E402

GROUND = 100.0
"""Side of the ground plane, metres, centred on the origin."""
GRID = 5
"""Blocks per side; the centre one is a square with the portico."""
BLOCK = 16.0
"""Block pitch, metres: a building of 8-12 m and a street."""
SUN_STRENGTH = 4.0
SUN_ELEVATION = math.radians(40.0)
SUN_AZIMUTH = math.radians(30.0)
SUN_ANGLE = math.radians(0.5)
WORLD_COLOUR = (0.45, 0.6, 1.0)
WORLD_STRENGTH = 1.0
COLOURS = ((0.75, 0.75, 0.75), (0.5, 0.5, 0.5), (0.8, 0.45, 0.3), (0.35, 0.35, 0.35), (0.85, 0.8, 0.6),
           (0.3, 0.45, 0.6))
"""Albedos the buildings take in turn (plaster, concrete, brick, slate, sandstone, blue paint)."""


def layout(seed: int = 7) -> list:
    """[(name, boxes, albedo (3,)), ...]: the buildings on the grid (seeded: the same town every run)."""
    rng = np.random.default_rng(seed)
    out = []
    half = (GRID - 1) / 2
    for i in range(GRID):
        for j in range(GRID):
            cx, cy = (i - half) * BLOCK, (j - half) * BLOCK
            colour = COLOURS[(i * GRID + j) % len(COLOURS)]
            if i == j == GRID // 2:  # the square: a portico, a 12 x 6 m slab on six pillars, 5 m up
                slab = [((cx - 6, cy - 3, 5.0), (cx + 6, cy + 3, 5.6))]
                pillars = [((x - 0.3, y - 0.3, 0.0), (x + 0.3, y + 0.3, 5.0)) for x in (cx - 5.4, cx, cx + 5.4)
                           for y in (cy - 2.4, cy + 2.4)]
                out.append(("Portico", slab + pillars, (0.8, 0.78, 0.72)))
                continue
            w, d = rng.uniform(8, 12, 2)
            h = float(rng.uniform(4, 24))
            boxes = [((cx - w / 2, cy - d / 2, 0.0), (cx + w / 2, cy + d / 2, h))]
            if (i + 2 * j) % 7 == 0:  # stepped: a narrower storey on top, its roof a terrace round it
                boxes.append(((cx - w / 4, cy - d / 4, h), (cx + w / 4, cy + d / 4, h + 6.0)))
            out.append((f"Building_{i}{j}", boxes, colour))
    return out


def build() -> list:
    """A factory-fresh file with the town, the sun and the sky; returns the mesh objects."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    _world(bpy, WORLD_COLOUR, WORLD_STRENGTH)
    objects = []
    g = GROUND / 2
    ground = bpy.data.meshes.new("Ground")
    ground.from_pydata([(-g, -g, 0), (g, -g, 0), (g, g, 0), (-g, g, 0)], [], [(0, 1, 2, 3)])
    ground.materials.append(_diffuse_material(bpy, "GroundMat", (0.4, 0.4, 0.38)))
    objects.append(bpy.data.objects.new("Ground", ground))
    for name, boxes, albedo in layout():
        mesh = boxes_mesh(name, boxes)
        mesh.materials.append(_diffuse_material(bpy, name + "Mat", albedo))  # one each: one Cycles call
        objects.append(bpy.data.objects.new(name, mesh))
    for ob in objects:
        bpy.context.scene.collection.objects.link(ob)
    sun = bpy.data.lights.new("Sun", "SUN")
    sun.energy = SUN_STRENGTH
    sun.angle = SUN_ANGLE
    sun_ob = bpy.data.objects.new("Sun", sun)
    sun_ob.rotation_euler = (math.pi / 2 - SUN_ELEVATION, 0.0, SUN_AZIMUTH)
    bpy.context.scene.collection.objects.link(sun_ob)
    bpy.context.view_layer.update()
    return objects


def digest(objects) -> str:
    """8 hex digits of the town as Cycles sees it: a cached reference is for it only."""
    h = hashlib.sha1()
    for ob in objects:
        co = np.empty(len(ob.data.vertices) * 3, np.float64)
        ob.data.vertices.foreach_get("co", co)
        h.update(co.tobytes())
    h.update(repr((SUN_STRENGTH, SUN_ELEVATION, SUN_AZIMUTH, SUN_ANGLE, WORLD_COLOUR, WORLD_STRENGTH)).encode())
    return h.hexdigest()[:8]


def reference(objects, sizes: dict, passes: str, spp: int, bounces: int, folder: Path) -> tuple:
    """({name: (seed-1 bake, seed-2 bake)} of one pass, {name: (H, W) bool texels Cycles bakes (margin 0)},
    Cycles' seconds) for every object; cached."""
    cached = folder / f"reference_{digest(objects)}_{passes}_{spp}spp_{bounces}b.npz"
    if cached.exists():
        with np.load(cached) as f:
            return ({ob.name: (f[ob.name + ":1"], f[ob.name + ":2"]) for ob in objects},
                    {ob.name: f[ob.name + ":covered"] for ob in objects}, float(f["seconds"]))
    out, covered, seconds = {ob.name: [] for ob in objects}, {}, 0.0
    for seed in (1, 2):
        for ob in objects:  # one call per object: each its own image size
            W, H = sizes[ob.name]
            t = time.perf_counter()
            bake = cr.cycles_bake_full([ob], LIGHTMAP_UV, W, H, {passes}, spp, seed=seed, diffuse_bounces=bounces,
                                       clamp_indirect=0.0)
            seconds += time.perf_counter() - t
            out[ob.name].append(bake.images[ob.name][..., :3])
            covered[ob.name] = bake.coverage[ob.name]
    np.savez_compressed(cached, seconds=seconds, **{f"{k}:{s + 1}": v[s] for k, v in out.items() for s in (0, 1)},
                        **{f"{k}:covered": v for k, v in covered.items()})
    return {k: tuple(v) for k, v in out.items()}, covered, seconds


def kind(name: str) -> str:
    return "ground" if name == "Ground" else "portico" if name == "Portico" else "buildings"


def main(argv=None):
    run_scene("town", build, kind, argv, density=2.0, spp=256)


def run_scene(name: str, build_scene, kind, argv=None, density: float = 2.0, spp: int = 256) -> None:
    """A many-object bench scene end to end: ``build_scene()`` (its mesh objects), PDIC through the add-on,
    the Cycles pairs, the errors per ``kind(object name)`` (:func:`compare`), and ``--competitors``.
    density, spp : the scene's default texels per metre and reference samples."""
    ap = argparse.ArgumentParser(prog=f"bench/{name}.py")
    ap.add_argument("--density", type=float, default=density, help="texels per metre")
    ap.add_argument("--spp", type=int, default=spp)
    ap.add_argument("--bounces", type=int, default=32)
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0, help="PDIC's seed")
    ap.add_argument("--quality", default="FINAL", choices=("PREVIEW", "FINAL"))
    ap.add_argument("--deviations", default="", help="switches as bench/run.py's, e.g. sky_gathering=0")
    ap.add_argument("--set", default="", help="BakeSettings overrides, e.g. r_min_texels=3,a=0.5")
    ap.add_argument("--competitors", default="", help="Cycles + OIDN at these samples, e.g. 4,16,64")
    ap.add_argument("--out", default=f"/tmp/pdic_{name}")
    args = ap.parse_args(argv)
    folder = Path(args.out)
    folder.mkdir(parents=True, exist_ok=True)
    pdic_addon.register()
    objects = build_scene()
    job, wall, cpu = bake_job(args, folder)
    result = job.result
    writeback.set_shading(objects, baked=False)  # Cycles bakes the objects' own materials
    sizes = {ob.name: result.direct[ob.name].shape[1::-1] for ob in objects}
    counters = result.stats["counters"]
    texels = sum(int(result.centre_inside[ob.name].sum()) for ob in objects)
    print(f"{name}: {len(objects)} objects, {texels:,} texels at {args.density:g} texels/m; PDIC "
          f"{args.quality.title()} {wall:.1f} s wall, {cpu:.1f} CPU s (unwrap included), records "
          f"{counters.get('records_total', 0):,} ({counters.get('hole_records', 0):,} hole records), photons stored "
          f"{counters.get('photons_stored', 0):,}, sky gathered {counters.get('sky_gathered', 0)}; "
          f"stages (wall s) {', '.join(f'{k} {v:.1f}' for k, v in result.stats.get('seconds', {}).items())}")
    compare(objects, result, sizes, args, folder, kind)
    if args.competitors:
        competitors(objects, sizes, result, [int(spp) for spp in args.competitors.split(",")], cpu, args, folder)

def compare(objects, result, sizes: dict, args, folder: Path, kind) -> None:
    """Print PDIC's direct and indirect light against the Cycles pairs (:func:`reference`), per object kind
    (``kind(name)``) and over all, and save PDIC's maps in ``folder``."""
    for passes, images in (("DIRECT", result.direct), ("INDIRECT", result.indirect)):
        pairs, covered, seconds = reference(objects, sizes, passes, args.spp, args.bounces, folder)
        print(f"{passes.lower()}: Cycles {args.spp} spp x 2 ({seconds:.0f} s)")
        groups = {}
        for ob in objects:
            C1, C2 = pairs[ob.name]
            both = covered[ob.name] & result.centre_inside[ob.name]
            baked = ((C1.sum(axis=2) > 0) | (C2.sum(axis=2) > 0)) & both
            groups.setdefault(kind(ob.name), []).append((images[ob.name], C1, C2, baked, both))
        groups["all"] = [entry for key in list(groups) for entry in groups[key]]
        for key, entries in groups.items():
            print(f"  {key:9s} " + describe(summary(entries)))
    np.savez_compressed(folder / f"pdic_seed{args.seed}.npz",
                        **{f"{ob.name}:{p}": getattr(result, p)[ob.name] for ob in objects for p in ("direct", "indirect")})


def competitors(objects, sizes: dict, result, ladder: list, pdic_cpu: float, args, folder: Path) -> None:
    """Cycles + OIDN against PDIC on direct+indirect over every object's texels (bench/daylight_room.py's
    rows: Cycles Diffuse Direct+Indirect at seed 0 with a 16-texel margin, raw and denoised by OIDN RT and
    RTLightmap, against the sum of the two reference pairs; CPU seconds summed over the objects)."""
    (direct, covered, _), (indirect, _, _) = (reference(objects, sizes, passes, args.spp, args.bounces, folder)
                                             for passes in ("DIRECT", "INDIRECT"))
    pairs = {k: (direct[k][0] + indirect[k][0], direct[k][1] + indirect[k][1]) for k in direct}
    rows = [("PDIC " + args.quality.title() + " (unwrap included)", {k: result.as_cycles(k) for k in pairs}, pdic_cpu)]
    set_cycles_threads(2)
    warm_up_denoisers()
    for spp in ladder:
        raw, cpu = {}, 0.0
        for ob in objects:
            bake = cycles_bake(ob, tuple(sizes[ob.name]), frozenset({"DIRECT", "INDIRECT"}), spp, 0)
            raw[ob.name], cpu = bake["image"][..., :3], cpu + bake["cpu"]
        rows.append((f"Cycles {spp} spp", raw, cpu))
        for mode in ("RT", "RTLightmap"):
            out, extra = {}, 0.0
            for name, image in raw.items():
                out[name], _, seconds = clocked(denoise, image, mode, None)
                extra += seconds
            rows.append((f"Cycles {spp} spp + OIDN {mode}", out, cpu + extra))
    for method, images, cpu in rows:
        entries = []
        for ob in objects:
            C1, C2 = pairs[ob.name]
            both = covered[ob.name] & result.centre_inside[ob.name]
            entries.append((images[ob.name], C1, C2, ((C1.sum(axis=2) > 0) | (C2.sum(axis=2) > 0)) & both, both))
        err = summary(entries)
        print(f"{method:34s} {cpu:6.1f} CPU s; all objects {err['texel']:.2%} per texel, {err['block']:.2%} 8x8, "
              f"mean {err['mean']:.4f}")


def describe(err: dict) -> str:
    return (f"{err['texels']:7,} texels: per texel {err['texel']:.2%}, 8x8 {err['block']:.2%}, "
            f"mean {err['mean']:.4f}; Cycles' noise {err['noise']:.2%}; lit only in PDIC {err['only_pdic']:.2%}, "
            f"only in Cycles {err['only_cycles']:.2%}")


def summary(entries: list) -> dict:
    """Errors of several objects' maps as one: their texels stacked in one strip; the 8x8-block error is
    each object's, weighted by its texels. entries : (test, C1, C2, compared mask, texels both bake)."""
    blocks, dark_in_cycles, dark_in_pdic, count = [], 0, 0, 0
    P_all, A_all, B_all = [], [], []
    for P, C1, C2, baked, centre in entries:
        P_all.append(P[baked]), A_all.append(C1[baked]), B_all.append(C2[baked])
        mean = 0.5 * (C1 + C2)
        lum_p, lum_c = P[centre].sum(axis=1), mean[centre].sum(axis=1)
        level = max(float(lum_c.mean()), 1e-30)
        dark_in_cycles += int(((lum_c < 1e-3 * level) & (lum_p > 0.05 * level)).sum())
        dark_in_pdic += int(((lum_p < 1e-3 * level) & (lum_c > 0.05 * level)).sum())
        count += int(centre.sum())
        if baked.any():  # a prop's map Cycles leaves black (all in shadow) has no block error
            blocks.append(errors(P, (C1, C2), baked)["block"] ** 2 * baked.sum())
    P, A, B = (np.concatenate(v)[None] for v in (P_all, A_all, B_all))
    mask = np.ones(P.shape[:2], bool)
    err = errors(P, (A, B), mask, block=1)
    n = max(int(mask.sum()), 1)
    noise = float(np.sqrt(np.mean((A - B) ** 2) / 2) / max(float(0.5 * (A + B).mean()), 1e-30))
    return dict(texels=n, texel=err["texel"], block=math.sqrt(sum(blocks) / n), mean=err["mean_ratio"], noise=noise,
                only_pdic=dark_in_cycles / max(count, 1), only_cycles=dark_in_pdic / max(count, 1))


if __name__ == "__main__":
    main()
