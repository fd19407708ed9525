"""Small 8x8 blocks judged against a converged Cycles reference baked on them alone.

    .venv/bin/python bench/small_blocks.py [--scene sponza_held] [--spp 4096] [--seeds 0,1] [--paths 1024]
    .venv/bin/python bench/small_blocks.py --scene cathedral [--detail 0.3] [--res 512]

Issue #11 asks that no 8x8-texel block of the indirect light be off by more than 20 %. Blocks at a chart's
edge hold one to fifteen texels (Sponza held at 4 texels/m: 2,396 of 3,370), and a 512-spp reference pair
cannot judge a block of one texel: its own two seeds are more than 20 % apart at 70 of them. Baking the
whole map at 4,096 spp would take Cycles about 35 minutes here; this bench bakes only the polygons whose
``PDIC_Lightmap`` box touches a small block (``restricted_layer``: the other polygons' UVs are collapsed
onto one point in a copy of the layer, so they cover no texel but still cast shadows and reflect light;
Cycles' per-texel random numbers depend on the texel and the seed only, so a texel comes out as in the full
bake, tests/test_small_blocks.py). The pair (seeds 1 and 2, 64 diffuse bounces, no clamping) is cached in
bench/references/{scene}_small_blocks_{spp}x2_64_INDIRECT.npz (the cathedral's named by its detail, its mesh's
digest and its map's side; it has no held pair, so Cycles' coverage is taken as the texels whose centre lies
on a triangle).

PDIC Final (each ``--seeds``) is judged on the small blocks against the held pair, if any, and the converged
one; every block still off from the converged pair is traced over Cycles' footprint of its texels
(bench/referee_competitors.py ``traced_blocks``, bench/path_referee.py's tracer; ``--paths`` per point),
which says whose value it is:

- *reference noise*: the converged pair's own seeds are more than 20 % apart there;
- *partly inside*: some of the footprint's points lie inside closed geometry (traced black), which Cycles
  averages in and PDIC leaves out (docs/DEVIATIONS.md, texel-validity; README "Chart edges");
- *coincident faces*: another face passes within two ray offsets of a texel's samples
  (``bench.run.comparable_texels``): Cycles' bake rays, which leave the surface with no offset, meet it;
  PDIC's and the path tracer's do not (bench/coincident.py);
- *tracer with PDIC*: the path tracer over Cycles' own footprint is nearer PDIC's value than Cycles';
- *PDIC's own*: it is nearer Cycles'.

Given two seeds or more, the blocks are judged once more on PDIC's mean over the seeds (over the texels every
seed bakes), which halves PDIC's own noise at four seeds, and each block's spread over the seeds is reported:
a block off in one seed whose mean over the seeds is within 20 % is *PDIC's noise*. The mean's blocks still off
are traced and sorted as above.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
from bench import run as bench_run  # noqa: E402  (loads pdic and bpy)

from pdic.bench.competitors import BLOCK, BLOCK_OFF, block_counts, block_differences, block_means  # noqa: E402

SMALL = 16
"""A block holding fewer judged texels than this (of 64) is small: it lies at a chart's edge."""
REFEREE_POINTS = 8
"""Jittered points per axis over a texel's footprint that the path tracer traces (a sliver's texel keeps the
few of the 64 that land on its triangle: with 4 per axis, 1-3)."""
RESTRICT_UV = "PDIC_SmallBlocks"
"""The layer copy the restricted pair bakes into (removed with the scene: the bench's blend is not saved)."""


def polygons_touching(uv: np.ndarray, loop_total: np.ndarray, width: int, height: int,
                      blocks: np.ndarray) -> np.ndarray:
    """(P,) bool: polygons whose UV bounding box, one texel wider on each side, overlaps a block of ``blocks``
    ((H/8, W/8) bool). uv : (L, 2) float loop UVs in [0, 1], the polygons' loops in order; loop_total : (P,)."""
    polygon = np.repeat(np.arange(len(loop_total)), loop_total)
    x, y = uv[:, 0].astype(np.float64) * width, uv[:, 1].astype(np.float64) * height
    lo_x, hi_x, lo_y, hi_y = (np.full(len(loop_total), v) for v in (np.inf, -np.inf, np.inf, -np.inf))
    np.minimum.at(lo_x, polygon, x)
    np.maximum.at(hi_x, polygon, x)
    np.minimum.at(lo_y, polygon, y)
    np.maximum.at(hi_y, polygon, y)
    rows, cols = blocks.shape

    def block_index(v, size):
        return np.clip(np.floor(v) // BLOCK, 0, size - 1).astype(np.int64)

    x0, x1 = block_index(lo_x - 1, cols), block_index(hi_x + 1, cols)
    y0, y1 = block_index(lo_y - 1, rows), block_index(hi_y + 1, rows)
    table = np.zeros((rows + 1, cols + 1), np.int64)  # summed-area table of the chosen blocks
    table[1:, 1:] = blocks.cumsum(axis=0).cumsum(axis=1)
    return table[y1 + 1, x1 + 1] - table[y0, x1 + 1] - table[y1 + 1, x0] + table[y0, x0] > 0


def restricted_layer(mesh, source: str, keep: np.ndarray, width: int, height: int, name: str = RESTRICT_UV):
    """A copy ``name`` of ``mesh``'s UV layer ``source`` in which the polygons not in ``keep`` ((P,) bool) are
    collapsed onto the centre of texel (0, 0): a bake into it covers only the kept polygons' texels (and
    that one), and the geometry, hence the light, is the mesh's own."""
    from pdic.pdic_addon.uvmaps import read_uv

    uv = read_uv(mesh, source)
    loop_total = np.empty(len(mesh.polygons), np.int64)
    mesh.polygons.foreach_get("loop_total", loop_total)
    uv[~np.repeat(keep, loop_total)] = (0.5 / width, 0.5 / height)
    layer = mesh.uv_layers.new(name=name)
    layer.data.foreach_set("uv", uv.ravel())
    mesh.update()
    return layer


def restricted_pair(name: str, blocks: np.ndarray, spp: int, path: Path) -> tuple[list, float]:
    """(the pair as bench/run.py ``reference_pair`` reads it, its relative noise per bake): Cycles INDIRECT
    bakes (seeds 1, 2) of the converged scene ``name`` on the polygons touching ``blocks``, read from
    ``path`` when baked before."""
    from bench import converged_references as refs
    from bench import convergence

    if not path.exists():
        objects, scene = refs.one_object_scene(name, refs.PLAN[name]["density"], refs.SCENES / "cache" / name)
        held = convergence.load(name)[0]
        if not np.array_equal(scene.targets[0].lightmap_uv, held.targets[0].lightmap_uv):
            raise SystemExit(f"{name}: today's unwrap differs from the held scene's: bake the references again")
        restricted_bake(objects[0], scene.targets[0], blocks, spp, path)
    return bench_run.reference_pair(path)


def restricted_bake(ob, target, blocks: np.ndarray, spp: int, path: Path) -> None:
    """Bake Cycles' INDIRECT pair (seeds 1, 2) of mesh object ``ob`` on its polygons touching ``blocks`` of its
    core ``target`` (the object as the add-on extracted it, its ``PDIC_Lightmap`` written back) and save it
    to ``path`` (bench/converged_references.py ``save_pair``, keyed by the target's name)."""
    from bench import converged_references as refs
    from pdic.pdic_addon.uvmaps import LIGHTMAP_UV, read_uv

    loop_total = np.empty(len(ob.data.polygons), np.int64)
    ob.data.polygons.foreach_get("loop_total", loop_total)
    keep = polygons_touching(read_uv(ob.data), loop_total, target.width, target.height, blocks)
    restricted_layer(ob.data, LIGHTMAP_UV, keep, target.width, target.height)
    print(f"{ob.name}: {int(blocks.sum())} small blocks, {int(keep.sum())} of {len(keep)} polygons baked", flush=True)
    pair, seconds = refs.seed_pair([ob], RESTRICT_UV, {ob.name: (target.width, target.height)}, spp)
    for bake in pair:  # keyed by the core scene's target, as the other references
        bake["images"] = {target.name: bake["images"].pop(ob.name)}
        bake["coverage"] = {target.name: bake["coverage"].pop(ob.name)}
    refs.save_pair(path, pair, seconds, averaged=False)


def cathedral(detail: float, resolution: int, out: str) -> tuple:
    """(the cathedral object of bench/cathedral_indirect.py, baked once through the add-on so its
    ``PDIC_Lightmap`` is written back, the core scene the add-on extracted, the reference's file name)."""
    from bench.cathedral_indirect import bake_final, prepare, scene_digest
    from pdic.pdic_addon import writeback

    folder, ob = prepare(out, detail)
    job = bake_final(folder, resolution, 0)
    writeback.set_shading([ob], baked=False)  # Cycles bakes the object's own material, not the light map's
    return ob, job.extraction.scene, f"cathedral_d{detail:g}_{scene_digest(ob)}_{resolution}"


def judged_blocks(indirect: np.ndarray, mask: np.ndarray, reference: list, small: np.ndarray) -> dict:
    """Luminance of the 8x8 block means of ``indirect`` (H, W, 3) and of a pair ``reference`` (two dicts of
    images/coverage, one target) over ``mask`` (H, W) texels, on the ``small`` blocks the pair covers whole:
    {"judged": (H/8, W/8) bool, "rel": PDIC's relative difference from the pair's mean, "seeds": the
    pair's own, "pdic", "ref": the means}."""
    (a, b) = (next(iter(bake["images"].values())) for bake in reference)
    cov = next(iter(reference[0]["coverage"].values())) & next(iter(reference[1]["coverage"].values()))
    whole = block_counts(mask & cov) == block_counts(mask)
    rel, judged, pdic, ref = block_differences(indirect, 0.5 * (a + b), mask)
    seeds, _, _, _ = block_differences(a, b, mask)
    return dict(judged=judged & small & whole, rel=rel, seeds=seeds, pdic=pdic, ref=ref)


def verdict(pdic: float, cycles: float, traced: float, seeds: float, dark: int, coincident: int) -> str:
    """Whose value a block off from the converged pair holds (the module's docstring)."""
    if seeds > BLOCK_OFF:
        return "reference noise"
    if dark:
        return "partly inside"
    if coincident:
        return "coincident faces"
    return "tracer with PDIC" if abs(pdic - traced) < abs(cycles - traced) else "PDIC's own"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="sponza_held", help="a held converged scene (bench/convergence.py), or "
                    "cathedral (bench/cathedral_indirect.py's, baked through the add-on)")
    ap.add_argument("--detail", type=float, default=0.3, help="the cathedral's detail")
    ap.add_argument("--res", type=int, default=512, help="the cathedral's light-map side")
    ap.add_argument("--out", default="/tmp/pdic_small_blocks", help="the cathedral's output folder")
    ap.add_argument("--spp", type=int, default=4096, help="Cycles samples per bake of the restricted pair")
    ap.add_argument("--seeds", default="0,1", help="PDIC Final seeds judged")
    ap.add_argument("--paths", type=int, default=1024, help="path-traced paths per footprint point")
    args = ap.parse_args(argv)
    from bench import convergence
    from pdic.core.pipeline import bake
    from pdic.core.settings import preset
    from pdic.core.texels import lift_texels

    if args.scene == "cathedral":
        ob, scene, label = cathedral(args.detail, args.res, args.out)
        pair = None
    else:
        (scene, pair, _), label = convergence.load(args.scene), args.scene
    name = scene.targets[0].name
    centre = lift_texels(scene, 1)[1][0].centre_inside
    comparable = bench_run.comparable_texels(scene, preset("FINAL").texel_samples)[name]
    # Cycles bakes the texels whose centre lies on a triangle: the held pair's coverage, or those centres
    held = centre if pair is None else pair[0]["coverage"][name] & pair[1]["coverage"][name] & centre
    blocks = (block_counts(held) > 0) & (block_counts(held) < SMALL)
    path = bench_run.REFERENCES / f"{label}_small_blocks_{args.spp}x2_64_INDIRECT.npz"
    if pair is None:
        if not path.exists():
            restricted_bake(ob, scene.targets[0], blocks, args.spp, path)
        converged, noise = bench_run.reference_pair(path)
    else:
        converged, noise = restricted_pair(args.scene, blocks, args.spp, path)
    print(f"{label}: restricted pair {args.spp} spp x 2, noise {noise:.1%} per texel", flush=True)
    seeds = [int(s) for s in args.seeds.split(",")]
    maps, masks, offs = [], [], []
    for seed in seeds:
        result = bake(scene, replace(preset("FINAL"), seed=seed))
        mask = held & result.centre_inside[name] & ~result.buried[name]
        maps.append(result.indirect[name])
        masks.append(mask)
        fill = block_counts(mask)
        small_judged = (fill > 0) & (fill < SMALL)
        fine = judged_blocks(result.indirect[name], mask, converged, small_judged)
        judged, held_off = fine["judged"], ""
        if pair is not None:
            coarse = judged_blocks(result.indirect[name], mask, pair, small_judged)
            judged = judged & coarse["judged"]
            held_off = (f" (from the held pair {int((judged & (coarse['rel'] > BLOCK_OFF)).sum())}, whose own seeds "
                        f"are {BLOCK_OFF:.0%} apart at {int((judged & (coarse['seeds'] > BLOCK_OFF)).sum())})")
        off = [tuple(b) for b in np.argwhere(judged & (fine["rel"] > BLOCK_OFF))]
        offs.append(off)
        print(f"seed {seed}: {int(judged.sum())} small blocks judged; PDIC off by more than {BLOCK_OFF:.0%} from the "
              f"{args.spp}-spp pair at {len(off)}{held_off}; the {args.spp}-spp pair's seeds are that far apart at "
              f"{int((judged & (fine['seeds'] > BLOCK_OFF)).sum())}", flush=True)
        sort_off_blocks(scene, off, fine, fill, mask, comparable, args.paths, seed + 13)
    if len(seeds) > 1:
        over_seeds(scene, maps, masks, offs, converged, comparable, args.paths, seeds[0] + 17)


def sort_off_blocks(scene, off: list, fine: dict, fill: np.ndarray, mask: np.ndarray, comparable: np.ndarray,
                    paths: int, seed: int) -> None:
    """Trace the blocks ``off`` [(by, bx), ...] of a judgement ``fine`` (:func:`judged_blocks`) over the texels of
    ``mask`` and print whose value each holds (:func:`verdict`), then the count of each verdict."""
    from bench.referee_competitors import traced_blocks

    if not off:
        return
    traced, traced_se, black = traced_blocks(scene, "indirect", mask, np.array(off), paths, REFEREE_POINTS, seed)
    counts: dict = {}
    for (by, bx), truth, se, dark in zip(off, traced.mean(axis=1), traced_se, black):
        block = (slice(by * BLOCK, (by + 1) * BLOCK), slice(bx * BLOCK, (bx + 1) * BLOCK))
        coincident = int((mask[block] & ~comparable[block]).sum())
        why = verdict(fine["pdic"][by, bx], fine["ref"][by, bx], truth, fine["seeds"][by, bx], dark, coincident)
        counts[why] = counts.get(why, 0) + 1
        print(f"  {by:4d} {bx:4d} {fill[by, bx]:2d} texels  PDIC {fine['pdic'][by, bx]:.4f}  Cycles "
              f"{fine['ref'][by, bx]:.4f} (seeds {fine['seeds'][by, bx]:.0%} apart)  traced {truth:.4f} +- "
              f"{se:.4f}, {dark} footprint points black: {why}", flush=True)
    print("  " + ", ".join(f"{why} {n}" for why, n in sorted(counts.items())), flush=True)


def seed_spread(maps: list, mask: np.ndarray) -> np.ndarray:
    """(H/8, W/8) the relative standard deviation over the seeds of PDIC's block mean luminance over ``mask``'s
    texels, one map (H, W, 3) per seed in ``maps``: its own noise on each block."""
    lum = np.stack([block_means(m, mask)[0].mean(axis=2) for m in maps])
    return lum.std(axis=0, ddof=1) / np.maximum(lum.mean(axis=0), 1e-30)


def over_seeds(scene, maps: list, masks: list, offs: list, converged: list, comparable: np.ndarray, paths: int,
               seed: int) -> None:
    """Judge the small blocks on PDIC's mean over the seeds (``maps``, ``masks`` and each seed's blocks ``offs``
    as the seeds' bakes left them), over the texels every seed bakes; print PDIC's spread over the seeds, how
    many of each seed's blocks off are its noise (judged on the mean and within BLOCK_OFF there), and sort the
    mean's blocks still off (:func:`sort_off_blocks`)."""
    mask = np.logical_and.reduce(masks)
    fill = block_counts(mask)
    small = (fill > 0) & (fill < SMALL)
    fine = judged_blocks(np.mean(maps, axis=0), mask, converged, small)
    judged = fine["judged"]
    spread = seed_spread(maps, mask)[judged]
    mean_off = judged & (fine["rel"] > BLOCK_OFF)
    noise = [sum(1 for b in off if judged[b] and not mean_off[b]) for off in offs]
    print(f"the mean of {len(maps)} seeds: {int(judged.sum())} small blocks judged; PDIC's own spread over the seeds "
          f"{np.median(spread):.1%} median, {np.percentile(spread, 90):.1%} at the 90th percentile, "
          f"{np.percentile(spread, 99):.1%} at the 99th, {spread.max():.1%} at most; of each seed's blocks off, "
          f"PDIC's noise (the mean within {BLOCK_OFF:.0%}): {' / '.join(map(str, noise))}; the mean off at "
          f"{int(mean_off.sum())}", flush=True)
    sort_off_blocks(scene, [tuple(b) for b in np.argwhere(mean_off)], fine, fill, mask, comparable, paths, seed)


if __name__ == "__main__":
    main()
