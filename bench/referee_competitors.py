"""Which baker is right at the 8x8 blocks where PDIC Final and the competitors' Cycles reference differ most.

    .venv/bin/python bench/referee_competitors.py --scene sponza16 [--blocks 100] [--paths 64] [--kind all]

Reads what ``bash tools/bench.sh --only competitors`` left in ``bench/results/competitors/<scene>/``
(PDIC Final's map, the Cycles reference pair, Cycles' coverage; it bakes none of them again) and
rebuilds the same core scene from the unwrap cache. The competitors' error on 8x8 blocks weighs
every block alike, whatever the number of texels both bakers bake in it, so blocks of one or two
texels on a sliver chart count as much as full ones. For the ``--blocks`` blocks holding most of
PDIC's squared block error (noise subtracted), every texel both bake is path-traced over Cycles'
footprint (:func:`bench.path_referee.cycles_footprint`; indirect light by
:func:`bench.path_referee.mean_indirect`, and for ``--kind all`` the direct light at the same
points by next-event estimation), and the block's traced mean says which baker it sides with.
Prints the blocks, the counts, and PDIC's block error with the traced truth in place of the
pair's at those blocks (its standard error subtracted as the pair's noise is).

``--ladder`` also bakes Cycles' ladder again (the bench's seed: Cycles is deterministic per seed,
so these are the bench's images; its CPU seconds are the bench's, read from results.json),
denoises it the bench's three ways, and judges every rung by the same refereed truth: Cycles +
OIDN's CPU at PDIC's refereed error, over PDIC's. The blocks are picked by PDIC's difference from
the pair, so a block where PDIC and the pair share an error stays uncounted for both.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

RESULTS = ROOT / "bench" / "results" / "competitors"


def pair_blocks(pair: tuple, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(the pair's mean over each 8x8 block's masked texels (H/8, W/8, 3), its noise (a - b)^2 / 4 there, the
    blocks holding a masked texel): computed once, read by every image judged."""
    from pdic.bench.competitors import block_means

    (a, blocks), (b, _) = block_means(pair[0], mask), block_means(pair[1], mask)
    return 0.5 * (a + b), (a - b) ** 2 / 4, blocks


def worst_blocks(test: np.ndarray, pair: tuple, count: int) -> np.ndarray:
    """(k, 2) block rows and columns of the ``count`` blocks with the largest squared difference of ``test``'s
    block means (H/8, W/8, 3) from the pair's (:func:`pair_blocks`), less the pair's noise, channels averaged
    (``bench.competitors.errors``' block term), largest first."""
    ref, noise, blocks = pair
    excess = np.where(blocks, (((test - ref) ** 2) - noise).mean(axis=2), -np.inf)
    order = np.argsort(excess.ravel())[::-1][:count]
    return np.stack(np.unravel_index(order, excess.shape), axis=1)


def traced_blocks(scene, kind: str, mask: np.ndarray, chosen: np.ndarray, paths: int, per_axis: int, seed: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """((k, 3) traced E/pi mean over the masked texels of each block, (k,) its standard error, (k,) int the
    footprint points whose indirect light traced black: inside closed geometry): every texel path-traced over
    Cycles' footprint; ``kind`` "all" adds the direct light at the same points (one shadow ray per light and
    point: exact for point lights, whose noise the standard error then leaves out)."""
    from pdic.bench.path_referee import _traced_per_texel, cycles_footprint, mean_indirect
    from pdic.bench.competitors import BLOCK
    from pdic.core.direct import direct_irradiance
    from pdic.core.rays import RayCaster

    width, across = mask.shape[1], -(-mask.shape[1] // BLOCK)
    rows, cols = np.nonzero(mask)
    slot_of = np.full(-(-mask.shape[0] // BLOCK) * across, -1)  # block -> its index in ``chosen``
    slot_of[chosen[:, 0] * across + chosen[:, 1]] = np.arange(len(chosen))
    slot = slot_of[(rows // BLOCK) * across + cols // BLOCK]
    keep = slot >= 0
    texels, slot = rows[keep] * width + cols[keep], slot[keep]  # row-major order: sorted
    rng = np.random.default_rng(seed)
    caster = RayCaster(scene.geometry.positions)
    texel, p, n, n_g = cycles_footprint(scene, 0, texels, per_axis, rng, blender_52=False, geometric=True)
    mean, se = mean_indirect(scene, caster, p, n, paths, rng)
    point_slot = slot[np.searchsorted(texels, texel)]
    black = np.bincount(point_slot, weights=mean.mean(axis=1) < BLACK, minlength=len(chosen)).astype(np.int64)
    if kind == "all":
        mean = mean + direct_irradiance(scene, caster, p, n, n_g, 1, rng).E / np.pi
    per_texel, per_texel_se = _traced_per_texel(texels, texel, mean, se)
    count = np.maximum(np.bincount(slot, minlength=len(chosen)), 1)
    traced = np.stack([np.bincount(slot, weights=per_texel[:, c], minlength=len(chosen)) for c in range(3)], 1)
    variance = np.bincount(slot, weights=per_texel_se ** 2, minlength=len(chosen))
    return traced / count[:, None], np.sqrt(variance) / count, black


def refereed_block_error(test: np.ndarray, pair: tuple, chosen: np.ndarray, traced: np.ndarray,
                         traced_se: np.ndarray) -> tuple[float, float]:
    """(the noise-corrected relative RMSE of ``test``'s block means (H/8, W/8, 3) against the pair's
    (:func:`pair_blocks`), the same with the traced means (their variance subtracted) in place of the pair's
    at the ``chosen`` blocks)."""
    ref, noise, blocks = pair[0].copy(), pair[1].copy(), pair[2]  # the chosen blocks' entries are replaced
    sq = (test - ref) ** 2
    before = np.sqrt(max(sq[blocks].mean() - noise[blocks].mean(), 0.0)) / ref[blocks].mean()
    by, bx = chosen[:, 0], chosen[:, 1]
    ref[by, bx] = traced
    sq[by, bx] = (test[by, bx] - traced) ** 2
    noise[by, bx] = (traced_se ** 2)[:, None]
    after = np.sqrt(max(sq[blocks].mean() - noise[blocks].mean(), 0.0)) / ref[blocks].mean()
    return float(before), float(after)


BLACK = 1e-4
"""A footprint point whose traced indirect E/pi (its channels' mean) is below this is black: every path from it
met a back face (inside closed geometry; bench/small_blocks.py's *partly inside* blocks)."""
DARK_PAIR = 0.01
"""A block where the pair reads below this fraction of PDIC is one where Cycles' rays stopped at once (a twin
face in the same plane, or a face nearer than PDIC's ray offset): the trace shares that offset with PDIC,
so it is no independent judge there. The "independent" variant leaves such blocks to the pair."""


def refereed_ladder(obj, spec, kind: str, mask, normal, pair, variants: dict, bench_rows: list, pdic_row: dict
                    ) -> None:
    """Bake and denoise the ladder again and print, per variant (label -> (chosen blocks, traced means, their
    standard errors, PDIC's refereed error)), each rung's refereed block error and Cycles + OIDN's CPU
    seconds at PDIC's refereed error (the bench's CPU seconds per rung). pair : :func:`pair_blocks`."""
    from pdic.bench import competitors as comp

    comp.set_cycles_threads(2)
    comp.warm_up_denoisers()
    size = (mask.shape[1], mask.shape[0])
    rows = {label: [] for label in variants}
    for spp in spec.ladder:
        image = comp.cycles_bake(obj, size, comp.PASS_SETS[kind], spp, comp.LADDER_SEED)["image"]
        for method, img in [("Cycles", image)] + [(f"Cycles + OIDN {m}", comp.denoise(image, m, normal))
                                                   for m in comp.DENOISERS]:
            cpu = next(r["cpu"] for r in bench_rows if (r["method"], r["kind"], r["spp"]) == (method, kind, spp))
            errors = []
            test = comp.block_means(img, mask)[0]
            for label, (chosen, traced, traced_se, _) in variants.items():
                before, after = refereed_block_error(test, pair, chosen, traced, traced_se)
                rows[label].append(dict(method=method, kind=kind, cpu=cpu, error_block=after))
                errors.append(f"{label} {after:.2%}")
            print(f"  {method:24s} {spp:4d} spp  CPU {cpu:7.1f} s  8x8 against the pair {before:.2%}, refereed: "
                  + ", ".join(errors))
    for label, (_, _, _, refereed_pdic) in variants.items():
        print(f"  {label}: PDIC Final {pdic_row['cpu']:.1f} CPU s at {refereed_pdic:.2%}; Cycles' CPU there:")
        for method in sorted({r["method"] for r in rows[label]}):
            seconds, how = comp.cycles_cpu_at_error(rows[label], method, kind, "block", refereed_pdic)
            ratio = "-" if seconds is None else f"{seconds:,.0f} s ({seconds / pdic_row['cpu']:.2f}x, {how})"
            print(f"    {method:24s} {ratio}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="sponza16", help="a competitors scene key (bench/competitors.py SCENES)")
    ap.add_argument("--kind", default="all", choices=("all", "indirect"))
    ap.add_argument("--blocks", type=int, default=100)
    ap.add_argument("--paths", type=int, default=64, help="paths per footprint point")
    ap.add_argument("--per-axis", type=int, default=4, help="footprint points per texel axis")
    ap.add_argument("--seed", type=int, default=17)
    ap.add_argument("--ladder", action="store_true", help="judge Cycles' ladder by the refereed truth too")
    args = ap.parse_args(argv)

    import pdic_bootstrap

    pdic_bootstrap.load()
    from pdic import pdic_addon
    from pdic.bench import competitors as comp

    pdic_addon.register()
    spec, work = comp.SCENES[args.scene], RESULTS / args.scene
    if not (work / "pdic_final.npz").exists():
        sys.exit(f"referee_competitors: {work / 'pdic_final.npz'} is missing: run "
                 f"`bash tools/bench.sh --only competitors --competitors {args.scene}` first")
    obj, scene = comp.load_scene(spec, work)
    size = (scene.targets[0].width, scene.targets[0].height)
    key = comp.layout_key(obj)
    wanted = [comp.reference_path(work, comp.PASS_SETS[args.kind], size, spec.reference_spp, seed, key)
              for seed in comp.REFERENCE_SEEDS]
    wanted.append(comp.coverage_path(work, size, key))
    missing = [str(w) for w in wanted if not w.exists()]
    if missing:
        sys.exit(f"referee_competitors: not baked for this unwrap ({key}): {', '.join(missing)}")
    _, normal, centre = comp.texel_geometry(scene)
    mask = centre & np.load(wanted[2])
    pair = pair_blocks(tuple(np.load(w) for w in wanted[:2]), mask)
    x = comp.block_means(np.load(work / "pdic_final.npz")[args.kind], mask)[0]

    chosen = worst_blocks(x, pair, args.blocks)
    traced, traced_se, _ = traced_blocks(scene, args.kind, mask, chosen, args.paths, args.per_axis, args.seed)
    before, after = refereed_block_error(x, pair, chosen, traced, traced_se)
    lum_pdic, lum_pair = x[chosen[:, 0], chosen[:, 1]].mean(axis=1), pair[0][chosen[:, 0], chosen[:, 1]].mean(1)
    judged = lum_pair >= DARK_PAIR * lum_pdic
    variants = {"all audited": (chosen, traced, traced_se, after)}
    independent = refereed_block_error(x, pair, chosen[judged], traced[judged], traced_se[judged])[1]
    variants["independent"] = (chosen[judged], traced[judged], traced_se[judged], independent)
    counts = comp.block_counts(mask)
    pdic_nearer = 0
    print(f"{spec.label}, {args.kind}: the {len(chosen)} 8x8 blocks holding most of PDIC Final's squared block error "
          f"(block, texels both bake, E/pi luminance: PDIC / Cycles pair / path-traced +- its standard error)")
    for (by, bx), t, s in zip(chosen, traced, traced_se):
        mine, theirs, truth = float(x[by, bx].mean()), float(pair[0][by, bx].mean()), float(t.mean())
        nearer = abs(mine - truth) < abs(theirs - truth)
        pdic_nearer += nearer
        print(f"  {by:4d} {bx:4d} {int(counts[by, bx]):3d}  {mine:8.4f} {theirs:8.4f} {truth:8.4f} +- {s:.4f}  "
              f"{'PDIC' if nearer else 'Cycles'}")
    print(f"  nearer to path tracing: PDIC at {pdic_nearer}, the Cycles pair at {len(chosen) - pdic_nearer}")
    print(f"  PDIC's 8x8 block error against the pair {before:.2%}; with the traced truth at these blocks {after:.2%}; "
          f"at the {int(judged.sum())} where the pair is not dark ('independent', DARK_PAIR) {independent:.2%}")
    if args.ladder:
        import json

        bench = json.loads((ROOT / "bench" / "results" / "results.json").read_text())["competitors"]["scenes"]
        bench = bench[args.scene]
        pdic_row = next(r for r in bench["pdic"] if (r["method"], r["kind"]) == ("PDIC Final", args.kind))
        refereed_ladder(obj, spec, args.kind, mask, normal, pair, variants, bench["cycles"], pdic_row)


if __name__ == "__main__":
    main()
