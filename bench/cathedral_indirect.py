"""Cathedral (tests/cathedral.py): PDIC Final's indirect light against a converged Cycles pair, texel by texel.

    .venv/bin/python bench/cathedral_indirect.py [--detail 0.3] [--res 512] [--spp 1024] [--bounces 32]

The cathedral of bench/cathedral_direct.py (one mesh object, two point lights in the nave,
black world, one Diffuse BSDF material of albedo 0.8: not Blender's default surface, whose
specular layer takes 3 % of the indirect light, tests/test_cathedral_direct_vs_cycles.py). PDIC bakes Final at its defaults through the add-on's
``BakeJob``; Cycles bakes Diffuse Indirect (no Color, adaptive sampling off, ``--bounces``
diffuse bounces, sample clamping off) into the same ``PDIC_Lightmap`` UVs twice, with seeds 1
and 2: their mean is the reference and their difference its noise, which is subtracted
(bench/competitors.py ``errors``), cached in ``--out`` for the next run. Compared on texels both
baked.

Prints the noise-corrected relative RMSE per texel and on 8x8 blocks, the same over interior
texels (bench/run.py ``interior_texels``) and over comparable ones (``comparable_texels``: no other
face within two ray offsets of a sample), the mean ratio, and the share of 8x8 blocks off by
more than 20 % (blocks whose reference mean is above 5 % of the map's, so the noise of two
1,024-spp bakes cannot decide it), over all texels, comparable ones and those not buried (no part of
the footprint inside closed geometry, ``BakeResult.buried``), with the worst of them and the parts of the cathedral they
lie on. Writes the maps to ``--out``.
"""
from __future__ import annotations

import argparse
import hashlib
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
import pdic_bootstrap  # noqa: E402

pdic_bootstrap.load()
import bpy  # noqa: E402

import cycles_reference as cr  # noqa: E402
from bench.cathedral_direct import part, prepare, texel_geometry  # noqa: E402
from bench.competitors import BLOCK, BLOCK_OFF as OFF, block_counts, block_differences, errors  # noqa: E402
from bench.run import texel_masks  # noqa: E402
from test_cathedral_direct_vs_cycles import ALBEDO  # noqa: E402
from pdic.pdic_addon import job as job_module  # noqa: E402
from pdic.pdic_addon import writeback  # noqa: E402
from pdic.pdic_addon.properties import to_settings  # noqa: E402
from pdic.pdic_addon.uvmaps import LIGHTMAP_UV  # noqa: E402


def scene_digest(ob) -> str:
    """8 hex digits of the cathedral object as Cycles sees it (its mesh and its material's albedo):
    a cached reference is for that object only."""
    mesh = ob.data
    co = np.empty(len(mesh.vertices) * 3, np.float64)
    mesh.vertices.foreach_get("co", co)
    loops = np.empty(len(mesh.loops), np.int64)
    mesh.loops.foreach_get("vertex_index", loops)
    h = hashlib.sha1(co.tobytes())
    h.update(loops.tobytes())
    h.update(repr([m.name for m in mesh.materials] + [ALBEDO]).encode())
    return h.hexdigest()[:8]


def bake_final(folder: Path, resolution: int, threads: int):
    """PDIC Final at the defaults through BakeJob, every mesh of the file; returns the job."""
    props = bpy.context.scene.pdic
    props.quality = "FINAL"
    props.default_resolution = resolution
    props.image_format = "EXR_FLOAT"
    settings = to_settings(props, threads=threads)
    job = job_module.BakeJob(bpy.context, settings, output_folder=str(folder / "maps"),
                             cache_dir=folder / "unwrap_cache")
    job.run()
    return job


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--detail", type=float, default=0.3)
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--bounces", type=int, default=32)
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--worst", type=int, default=5, help="worst blocks listed")
    ap.add_argument("--out", default="/tmp/pdic_cathedral_indirect")
    args = ap.parse_args(argv)
    folder, ob = prepare(args.out, args.detail)
    t, cpu = time.perf_counter(), time.process_time()
    job = bake_final(folder, args.res, args.threads)
    pdic_s, pdic_cpu = time.perf_counter() - t, time.process_time() - cpu
    result = job.result
    P = result.indirect[ob.name]
    H, W = P.shape[:2]
    writeback.set_shading([ob], baked=False)  # the PDIC copies emit the light map: hide them
    cached = folder / f"reference_d{args.detail}_{scene_digest(ob)}_{W}x{H}_{args.spp}spp_{args.bounces}b.npz"
    pair, seconds = [], 0.0
    if cached.exists():  # the unwrap is deterministic: the same mesh, the same UVs, the same texels
        with np.load(cached) as f:
            pair, coverage, seconds = [f["C1"], f["C2"]], f["coverage"], float(f["seconds"])
    else:
        for seed in (1, 2):
            t = time.perf_counter()
            ref = cr.cycles_bake_full([ob], LIGHTMAP_UV, W, H, {"INDIRECT"}, args.spp, seed=seed,
                                      diffuse_bounces=args.bounces, clamp_indirect=0.0)
            seconds += time.perf_counter() - t
            pair.append(ref.images[ob.name][..., :3])
            coverage = ref.coverage[ob.name]
        np.savez_compressed(cached, C1=pair[0], C2=pair[1], coverage=coverage, seconds=seconds)
    baked = coverage & result.centre_inside[ob.name]
    interior, comparable = texel_masks(job.extraction.scene)[ob.name]
    np.savez_compressed(folder / f"d{args.detail}_{W}.npz", P=P, C1=pair[0], C2=pair[1], baked=baked,
                        interior=interior, comparable=comparable, buried=result.buried[ob.name])
    err = errors(P, tuple(pair), baked, interior)
    ntri = sum(len(p.vertices) - 2 for p in ob.data.polygons)
    print(f"detail {args.detail}: {ntri:,} triangles, map {W}x{H}, {int(baked.sum()):,} texels compared "
          f"({int((baked & interior).sum()):,} interior); PDIC Final {pdic_s:.1f} s wall, {pdic_cpu:.1f} CPU s "
          f"(unwrap included); Cycles {args.spp} spp x 2, {args.bounces} bounces, {seconds:.0f} s")
    seed_noise = np.sqrt(np.mean((pair[0] - pair[1])[baked] ** 2) / 2) / np.mean(0.5 * (pair[0] + pair[1])[baked])
    print(f"reference noise per texel (one bake) {seed_noise:.2%}")
    print(f"indirect, noise-corrected: per texel {err['texel']:.2%}, 8x8 blocks {err['block']:.2%}; interior "
          f"{err['texel_interior']:.2%} / {err['block_interior']:.2%}; mean / reference {err['mean_ratio']:.4f}")

    fair = errors(P, tuple(pair), baked & comparable)
    print(f"comparable texels ({int((baked & comparable).sum()):,}: no other face within two ray offsets of a "
          f"sample, bench/run.py comparable_texels): per texel {fair['texel']:.2%}, 8x8 blocks {fair['block']:.2%}")

    # Where every ray from a sample meets a back face (a capital top under an arch's mesh, which has no end
    # faces) PDIC's texel means hold 0, its light map the whole neighbours' light (docs/DEVIATIONS.md
    # buried-texels), while Cycles and the path referee find the light that enters through the opening.
    # No camera sees those parts of the texels.
    outside = baked & ~result.buried[ob.name]
    clear = errors(P, tuple(pair), outside)
    print(f"texels not buried ({int(outside.sum()):,}: no part inside closed geometry): per texel {clear['texel']:.2%}, "
          f"8x8 blocks {clear['block']:.2%}")

    reference = 0.5 * (pair[0] + pair[1])
    rel, lp, lc, count = blocks_off(P, reference, baked, "")
    blocks_off(P, reference, baked & comparable, "comparable texels: ")
    blocks_off(P, reference, outside, "texels not buried: ")
    order = np.argsort(rel, axis=None)[::-1][:args.worst]
    for y, x in zip(*np.unravel_index(order, rel.shape)):
        # The parts of the block's own texels: a chart fragment's block centre is often on no triangle.
        rows, cols = np.nonzero(baked[y * BLOCK:(y + 1) * BLOCK, x * BLOCK:(x + 1) * BLOCK])
        pos, nrm, _, _ = texel_geometry(ob, rows + y * BLOCK, cols + x * BLOCK, W, H)
        parts = Counter(part(p, n) for p, n in zip(pos, nrm) if np.isfinite(p).all())
        where = ", ".join(f"{name} {k}" for name, k in parts.most_common(2)) or "no texel on a triangle"
        print(f"  block ({y}, {x}), {int(count[y, x])} texels: PDIC {lp[y, x]:.4g}, Cycles {lc[y, x]:.4g} "
              f"({lp[y, x] / lc[y, x] - 1:+.1%}); {where}")


def blocks_off(P: np.ndarray, reference: np.ndarray, mask: np.ndarray, label: str):
    """Print how many judged 8x8 blocks of ``mask``'s texels are off by more than OFF; return (each block's
    relative difference (0 where not judged), PDIC's and the reference's block luminance, texels per block)."""
    rel, judged, lp, lc = block_differences(P, reference, mask)
    count = block_counts(mask)
    off = judged & (rel > OFF)
    print(f"{label}8x8 blocks judged {int(judged.sum()):,} of {int((count > 0).sum()):,}; off by > {OFF:.0%}: "
          f"{int(off.sum())} ({off.sum() / max(judged.sum(), 1):.2%}); worst {rel.max():.1%}")
    full = judged & (count >= BLOCK * BLOCK // 2)
    print(f"  of the {int(full.sum()):,} judged blocks with >= {BLOCK * BLOCK // 2} texels {int((off & full).sum())} "
          f"are off; of the {int((judged & (count == BLOCK * BLOCK)).sum()):,} full ones "
          f"{int((off & (count == BLOCK * BLOCK)).sum())}")
    return rel, lp, lc, count


if __name__ == "__main__":
    main()
