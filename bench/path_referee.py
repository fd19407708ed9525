"""A third opinion: brute-force diffuse path tracing at light-map texels, independent of both bakers.

    .venv/bin/python bench/path_referee.py --scene occluded [--texels 160] [--paths 4000]
    .venv/bin/python bench/path_referee.py --scene occluded --point=4.62,-0.08,0.1995/0,0,-1
    .venv/bin/python bench/path_referee.py --scene sponza_held --worst 100 --paths 64 [--seed 1] [--tag _b52]
    .venv/bin/python bench/path_referee.py --scene sponza_held --blocks --paths 64

When PDIC and a Cycles bake disagree, this says which one to believe. It shares only the scene
description and the ray caster with PDIC: no photons, no cache. Each path leaves the texel
sample cosine-distributed, takes the direct light at every vertex it reaches
(``core.direct.direct_irradiance``, next-event estimation) times the albedos so far, bounces
diffusely off either side of a triangle (as Cycles shades back faces) and ends by Russian
roulette on its throughput (at most ``MAX_BOUNCES``): an unbiased estimate of the indirect
irradiance E / pi, the light-map convention.

``--scene`` (a converged-bench scene, bench/convergence.py) compares, at ``--texels`` random
interior texels (``bench.run.interior_texels``: all 2x2 samples on the mesh), the Cycles pair
and a PDIC Final bake with the path-traced value of each texel (the mean over its samples, as
PDIC defines a texel). ``--point`` (repeatable) prints the path-traced value at a point instead.
``--worst N`` traces the N texels holding most of a Final bake's squared difference from the pair over
the footprint Cycles integrates (:func:`audit_worst`) and says which baker each sides with; ``--blocks``
does so for the 8x8 blocks off from the pair by more than 20 % (:func:`audit_blocks`).
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

MAX_BOUNCES = 64
"""Bounces a path may take before it is cut (Russian roulette ends nearly all far sooner)."""
ROULETTE_FLOOR = 0.05
"""Least survival probability of Russian roulette (its weight is at most 20)."""
CHUNK = 200_000
"""Paths traced together."""


def path_traced_indirect(scene, caster, p: np.ndarray, n: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(m, 3) one path's estimate of the indirect irradiance / pi at each point p facing n (m, 3)."""
    from pdic.core.albedo import albedo
    from pdic.core.direct import direct_irradiance

    faces = scene.geometry.face_normals()
    total = np.zeros((len(p), 3))
    weight = np.ones((len(p), 3))
    alive = np.arange(len(p))
    at, facing = np.array(p, np.float64), np.array(n, np.float64)
    for _ in range(MAX_BOUNCES):
        d = cosine_directions(facing[alive], rng)
        hits = caster.intersect(at[alive], d, facing[alive])
        alive, d = alive[hits.hit], d[hits.hit]
        if len(alive) == 0:
            break
        tri, bary = hits.triangle[hits.hit], hits.barycentric[hits.hit]
        x = at[alive] + d * hits.t[hits.hit, None]
        side = np.where((np.einsum("ij,ij->i", faces[tri], d) > 0)[:, None], -faces[tri], faces[tri])
        weight[alive] *= albedo(scene, tri, bary)
        total[alive] += weight[alive] * direct_irradiance(scene, caster, x, side, side, 1, rng).E
        survive = np.clip(weight[alive].max(axis=1), ROULETTE_FLOOR, 1.0)
        kept = rng.random(len(alive)) < survive
        weight[alive[kept]] /= survive[kept, None]
        alive = alive[kept]
        at[alive], facing[alive] = x[kept], side[kept]
    return total / np.pi


def cosine_directions(n: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(m, 3) unit directions, cosine-distributed about the unit normals n (m, 3)."""
    from pdic.core.sampling import cosine_hemisphere, to_world

    return to_world(cosine_hemisphere(rng.random((len(n), 2)))[0], n)


def mean_indirect(scene, caster, p: np.ndarray, n: np.ndarray, paths: int, rng: np.random.Generator
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(m, 3) mean of ``paths`` path estimates at each point, and (m,) the standard error of its RGB mean."""
    p, n = np.atleast_2d(p), np.atleast_2d(n)
    sums, squares = np.zeros((len(p), 3)), np.zeros(len(p))
    per_chunk = max(1, CHUNK // max(len(p), 1))
    done = 0
    while done < paths:
        k = min(per_chunk, paths - done)
        E = path_traced_indirect(scene, caster, np.repeat(p, k, axis=0), np.repeat(n, k, axis=0), rng)
        E = E.reshape(len(p), k, 3)
        sums += E.sum(axis=1)
        squares += (E.mean(axis=2) ** 2).sum(axis=1)
        done += k
    mean = sums / paths
    variance = np.maximum(squares / paths - mean.mean(axis=1) ** 2, 0.0)
    return mean, np.sqrt(variance / paths)


def referee_texels(name: str, texels: int, paths: int, seed: int = 11) -> dict:
    """Cycles pair and PDIC Final against path tracing at random interior texels of a converged scene."""
    from bench import convergence
    from bench.run import interior_texels
    from pdic.core import texels as texel_stage
    from pdic.core.pipeline import bake
    from pdic.core.rays import RayCaster
    from pdic.core.settings import preset

    scene, pair, _ = convergence.load(name)
    interior = interior_texels(scene)
    caster = RayCaster(scene.geometry.positions)
    rng = np.random.default_rng(seed)
    pdic = bake(scene, preset("FINAL"))
    rows = {"pt": [], "pt_se": [], "cycles": [], "cycles_a": [], "cycles_b": [], "pdic": []}
    per_target = max(1, texels // len(scene.targets))
    for target in scene.targets:
        name_t = target.name
        points, rasters = texel_stage.lift_texels(replace(scene, targets=(target,)), 2)
        usable = (pair[0]["coverage"][name_t] & pair[1]["coverage"][name_t] & interior[name_t]
                  & pdic.centre_inside[name_t])
        candidates = np.flatnonzero(usable.ravel())
        pick = rng.choice(candidates, size=min(per_target, len(candidates)), replace=False)
        W = rasters[0].coverage.shape[1]
        for texel in pick:
            samples = np.flatnonzero(points.texel == texel)
            mean, se = mean_indirect(scene, caster, points.p[samples], points.n_shading[samples],
                                     max(1, paths // len(samples)), rng)
            y, x = divmod(int(texel), W)
            rows["pt"].append(mean.mean(axis=0))
            rows["pt_se"].append(float(np.sqrt(np.mean(se ** 2) / len(samples))))
            rows["cycles_a"].append(pair[0]["images"][name_t][y, x])
            rows["cycles_b"].append(pair[1]["images"][name_t][y, x])
            rows["cycles"].append(0.5 * (rows["cycles_a"][-1] + rows["cycles_b"][-1]))
            rows["pdic"].append(pdic.indirect[name_t][y, x])
    return {k: np.asarray(v) for k, v in rows.items()}


WORST_POINTS_PER_AXIS = 8
"""Jittered points per texel axis over a Cycles footprint (:func:`cycles_footprint`)."""


def cycles_footprint(scene, target_index: int, texels: np.ndarray, per_axis: int, rng: np.random.Generator,
                     blender_52: bool, geometric: bool = False) -> tuple:
    """(texel (s,), p (s, 3), n (s, 3) shading normals), and with ``geometric`` (s, 3) geometric normals:
    stratified jittered points over the footprints of ``texels`` (flat indices of target ``target_index``)
    as Cycles' bake integrates them.

    Blender 5.0 and 5.1 jitter over the centred half-texel square and keep the points on the triangle under
    the texel's centre (:attr:`core.raster.TexelSamples.centre_triangle`; a texel none of whose points land
    there takes its centre). Blender 5.2 jitters over the whole texel and keeps the points that land on the
    chart (:func:`core.texels.footprint_texel_points`)."""
    from pdic.core.raster import on_centre_triangles, rasterize
    from pdic.core.texels import footprint_texel_points, on_surface

    target = scene.targets[target_index]
    if blender_52:
        fp = footprint_texel_points(scene, target_index, texels, per_axis, rng, 1.0)
        return (fp.texel, fp.p, fp.n_shading) + ((fp.n_geometric,) if geometric else ())
    g = scene.geometry
    local = np.flatnonzero(g.areas()[target.triangles] > 0)  # the triangles the light map's raster holds
    centre_triangle = rasterize(target.lightmap_uv[local], target.width, target.height, 1).centre_triangle
    m = per_axis
    strata = np.stack(np.meshgrid(np.arange(m), np.arange(m), indexing="xy"), axis=-1).reshape(-1, 2)
    jitter = 0.5 * (strata[None] + rng.random((len(texels), m * m, 2))) / m - 0.25  # the centred half texel
    uv = target.lightmap_uv[local].astype(np.float64) * [target.width, target.height]
    texel, tri, b, _ = on_centre_triangles(uv, target.width, texels, centre_triangle.reshape(-1)[texels], jitter)
    p, n, n_g = on_surface(g, g.face_normals(), target.triangles[local[tri]], b)
    return (texel, p, n) + ((n_g,) if geometric else ())


def _compared(pdic, pair, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mask (H, W): texels both Cycles bakes and PDIC's centres cover, the pair's mean (H, W, 3), each
    texel's squared difference from it less the pair's noise, channels averaged (H, W)) of target ``name``,
    as :func:`bench.run.noise_corrected_error` weighs them."""
    a, b = pair[0]["images"][name], pair[1]["images"][name]
    mask = pair[0]["coverage"][name] & pair[1]["coverage"][name] & pdic.centre_inside[name]
    ref = 0.5 * (a + b)
    return mask, ref, (((pdic.indirect[name] - ref) ** 2) - (a - b) ** 2 / 4).mean(axis=2)


def _traced_per_texel(texels: np.ndarray, texel: np.ndarray, mean: np.ndarray, se: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """((k, 3) mean, (k,) its standard error) of :func:`mean_indirect`'s values ``mean`` (s, 3), ``se`` (s,)
    at footprint points of ``texel`` (s,), per texel of ``texels`` (k,) sorted."""
    slot = np.searchsorted(texels, texel)
    count = np.maximum(np.bincount(slot, minlength=len(texels)), 1)
    traced = np.stack([np.bincount(slot, weights=mean[:, c], minlength=len(texels)) for c in range(3)], axis=1)
    return traced / count[:, None], np.sqrt(np.bincount(slot, weights=se ** 2, minlength=len(texels))) / count


def _audited_bake(name: str, tag: str, seed: int):
    """(core scene, Cycles pair, PDIC Final bake, whether the pair is Blender 5.2's) of a converged scene; the
    bake takes the footprint the add-on sets for that Blender."""
    from bench import convergence
    from pdic.core.pipeline import bake
    from pdic.core.settings import preset

    scene, pair, _ = convergence.load(name, tag)
    blender_52 = tag == "_b52"
    settings = preset("FINAL", seed=seed)
    if blender_52:
        settings = replace(settings, direct_footprint_side=1.0)
    return scene, pair, bake(scene, settings), blender_52


def audit_worst(name: str, worst: int, paths: int, tag: str = "", seed: int = 0, per_axis: int =
                WORST_POINTS_PER_AXIS) -> dict:
    """The ``worst`` texels of a PDIC Final bake (seed ``seed``) holding most of its squared error against a
    converged scene's Cycles pair (noise subtracted), path-traced over their Cycles footprints
    (:func:`cycles_footprint`, ``paths`` paths per point): which baker each texel's truth sides with,
    and the map's error with the path-traced values in place of the pair's at those texels."""
    from bench.run import noise_corrected_error
    from pdic.core.rays import RayCaster

    scene, pair, pdic, blender_52 = _audited_bake(name, tag, seed)
    rows = []
    for index, target in enumerate(scene.targets):
        mask, _, excess = _compared(pdic, pair, target.name)
        share = np.where(mask, excess, 0.0).ravel()
        rows += [(float(share[texel]), index, int(texel)) for texel in np.argsort(share)[::-1][:worst]]
    rows = sorted(rows, reverse=True)[:worst]
    caster = RayCaster(scene.geometry.positions)
    rng = np.random.default_rng(seed + 11)
    found = {"texel": [], "target": [], "pdic": [], "cycles_a": [], "cycles_b": [], "pt": [], "pt_se": []}
    for index, target in enumerate(scene.targets):
        chosen = np.array([t for _, i, t in rows if i == index], np.int64)
        if len(chosen) == 0:
            continue
        texel, p, n = cycles_footprint(scene, index, chosen, per_axis, rng, blender_52)
        order = np.argsort(chosen)
        traced, traced_se = _traced_per_texel(chosen[order], texel, *mean_indirect(scene, caster, p, n, paths, rng))
        back = np.argsort(order)  # sorted rows back to ``chosen``'s order
        for t, pt, pt_se in zip(chosen, traced[back], traced_se[back]):
            y, x = divmod(int(t), target.width)
            found["texel"].append((y, x))
            found["target"].append(target.name)
            found["pt"].append(pt)
            found["pt_se"].append(float(pt_se))
            found["pdic"].append(pdic.indirect[target.name][y, x])
            found["cycles_a"].append(pair[0]["images"][target.name][y, x])
            found["cycles_b"].append(pair[1]["images"][target.name][y, x])
    out = {k: np.asarray(v) for k, v in found.items() if k != "target"}
    out["target"] = found["target"]
    out["error"] = noise_corrected_error(pdic.indirect, pdic.centre_inside, pair)
    out["error_refereed"] = refereed_error(pdic, pair, out)
    return out


BLOCK_POINTS_PER_AXIS = 4
"""Jittered points per texel axis over a Cycles footprint in :func:`audit_blocks` (a block's mean averages
its texels' noise)."""


def audit_blocks(name: str, paths: int, tag: str = "", seed: int = 0, per_axis: int = BLOCK_POINTS_PER_AXIS
                 ) -> dict:
    """The 8x8 blocks of a PDIC Final bake (seed ``seed``) off from a converged scene's Cycles pair by more
    than BLOCK_OFF over the texels not buried (``bench.convergence``'s ``blocks_judged_off_outside``), every
    texel of them path-traced over its Cycles footprint (:func:`cycles_footprint`, ``paths`` paths per
    point): how many are off from the traced truth for PDIC and for the pair.
    Returns {"blocks": [(target, by, bx, PDIC, pair, traced, its standard error)], "judged": blocks judged}."""
    from pdic.bench.competitors import BLOCK, BLOCK_OFF, block_differences
    from pdic.core.rays import RayCaster

    scene, pair, pdic, blender_52 = _audited_bake(name, tag, seed)
    caster = RayCaster(scene.geometry.positions)
    rng = np.random.default_rng(seed + 13)
    rows, judged_all = [], 0
    for index, target in enumerate(scene.targets):
        n_t = target.name
        mask, ref, _ = _compared(pdic, pair, n_t)
        mask &= ~pdic.buried[n_t]
        rel, judged, mine, theirs = block_differences(pdic.indirect[n_t], ref, mask)
        judged_all += int(judged.sum())
        off = np.argwhere(judged & (rel > BLOCK_OFF))
        if len(off) == 0:
            continue
        cells = np.zeros(mask.shape, bool)
        for by, bx in off:
            cells[by * BLOCK:(by + 1) * BLOCK, bx * BLOCK:(bx + 1) * BLOCK] = True
        texels = np.flatnonzero((cells & mask).ravel())
        texel, p, n = cycles_footprint(scene, index, texels, per_axis, rng, blender_52)
        traced, traced_se = _traced_per_texel(texels, texel, *mean_indirect(scene, caster, p, n, paths, rng))
        traced = traced.mean(axis=1)
        y, x = np.divmod(texels, target.width)
        for by, bx in off:
            inside = (y // BLOCK == by) & (x // BLOCK == bx)
            rows.append((n_t, int(by), int(bx), float(mine[by, bx]), float(theirs[by, bx]),
                         float(traced[inside].mean()), float(np.sqrt((traced_se[inside] ** 2).sum()) / inside.sum())))
    return {"blocks": rows, "judged": judged_all}


def refereed_error(pdic, pair, audit: dict) -> float:
    """:func:`bench.run.noise_corrected_error` of ``pdic``'s indirect light with the audited texels' truth
    taken from path tracing (its variance subtracted) instead of the Cycles pair."""
    sq, count, total = 0.0, 0, 0.0
    for n_t in pdic.indirect:
        mask, ref, excess = _compared(pdic, pair, n_t)
        truth = ref.mean(axis=2)
        for (y, x), target, pt, se in zip(audit["texel"], audit["target"], audit["pt"], audit["pt_se"]):
            if target == n_t and mask[y, x]:
                excess[y, x] = float(((pdic.indirect[n_t][y, x] - pt) ** 2).mean()) - se ** 2
                truth[y, x] = float(pt.mean())
        sq, count, total = sq + excess[mask].sum(), count + int(mask.sum()), total + truth[mask].sum()
    return float(np.sqrt(max(sq / max(count, 1), 0.0)) / max(total / max(count, 1), 1e-30))


def print_audit(scene: str, audit: dict) -> None:
    """:func:`audit_worst`'s table (E/pi over the pair's mean at the texels, luminance) and verdict."""
    pt, se = audit["pt"].mean(axis=1), audit["pt_se"]
    pdic, cycles = audit["pdic"].mean(axis=1), 0.5 * (audit["cycles_a"] + audit["cycles_b"]).mean(axis=1)
    nearer = np.abs(pdic - pt) < np.abs(cycles - pt)
    print(f"{scene}: the {len(pt)} texels holding most of PDIC's squared error (y, x: PDIC / Cycles pair / "
          f"path-traced over Cycles' footprint +- its standard error)")
    for (y, x), p, c, t, s, mine in zip(audit["texel"], pdic, cycles, pt, se, nearer):
        print(f"  {y:5d} {x:5d}  {p:8.4f} {c:8.4f} {t:8.4f} +- {s:.4f}  {'PDIC' if mine else 'Cycles'}")
    print(f"  nearer to path tracing: PDIC at {int(nearer.sum())}, Cycles at {int((~nearer).sum())}")
    print(f"  error against the pair {audit['error']:.2%}; with the path-traced truth at these texels "
          f"{audit['error_refereed']:.2%}")


def print_block_audit(scene: str, audit: dict) -> None:
    """:func:`audit_blocks`' table (block means, E/pi luminance) and counts."""
    from pdic.bench.competitors import BLOCK_OFF

    rows = audit["blocks"]
    print(f"{scene}: {len(rows)} of {audit['judged']} 8x8 blocks (texels not buried) off from the Cycles pair by more "
          f"than {BLOCK_OFF:.0%} (block, PDIC / pair / path-traced over Cycles' footprints +- its error)")
    pdic_off = cycles_off = 0
    for target, by, bx, mine, theirs, traced, se in rows:
        p_off, c_off = abs(mine / traced - 1) > BLOCK_OFF, abs(theirs / traced - 1) > BLOCK_OFF
        pdic_off, cycles_off = pdic_off + p_off, cycles_off + c_off
        print(f"  {target} {by:4d} {bx:4d}  {mine:8.4f} {theirs:8.4f} {traced:8.4f} +- {se:.4f}  "
              f"{'PDIC off ' if p_off else ''}{'pair off' if c_off else ''}")
    print(f"  off from the trace by more than {BLOCK_OFF:.0%}: PDIC {pdic_off}, the pair {cycles_off}")


def agreement(test: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(relative RMS difference, mean bias) of ``test`` against ``truth`` (texels x 3)."""
    return (float(np.sqrt(np.mean((test - truth) ** 2)) / max(truth.mean(), 1e-30)),
            float(test.sum() / max(truth.sum(), 1e-30) - 1.0))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="occluded", help="a converged-bench scene: cornell, occluded, sponza")
    ap.add_argument("--texels", type=int, default=160)
    ap.add_argument("--paths", type=int, default=4000, help="paths per texel (or per point)")
    ap.add_argument("--worst", type=int, default=0, help="audit the N texels holding most of a Final bake's "
                    "squared error against the scene's Cycles pair instead (paths per footprint point)")
    ap.add_argument("--blocks", action="store_true", help="trace the 8x8 blocks a Final bake has off from the "
                    "scene's Cycles pair by more than 20 %% instead (paths per footprint point)")
    ap.add_argument("--tag", default="", help="the references' tag (bench/convergence.py --tag), e.g. _b52")
    ap.add_argument("--seed", type=int, default=0, help="the audited PDIC bake's seed")
    ap.add_argument("--point", action="append", help="x,y,z/nx,ny,nz in the scene's local space (write "
                    "--point=... when it starts with a minus)")
    args = ap.parse_args(argv)
    from bench import run as bench_run  # noqa: F401  (loads pdic and bpy)

    if args.point:
        from bench import convergence
        from pdic.core.rays import RayCaster

        scene = convergence.load(args.scene)[0]
        caster = RayCaster(scene.geometry.positions)
        for spec in args.point:
            p, n = ([float(v) for v in part.split(",")] for part in spec.split("/"))
            mean, se = mean_indirect(scene, caster, np.array(p), np.array(n) / np.linalg.norm(n), args.paths,
                                     np.random.default_rng(7))
            print(f"{spec}: E/pi {np.round(mean[0], 4)} (+- {se[0]:.4f})")
        return
    if args.worst:
        print_audit(args.scene, audit_worst(args.scene, args.worst, args.paths, args.tag, args.seed))
        return
    if args.blocks:
        print_block_audit(args.scene, audit_blocks(args.scene, args.paths, args.tag, args.seed))
        return
    r = referee_texels(args.scene, args.texels, args.paths)
    noise_pt = float(np.sqrt(np.mean(r["pt_se"] ** 2)) / r["pt"].mean())
    noise_cycles = float(np.sqrt(np.mean((r["cycles_a"] - r["cycles_b"]) ** 2) / 4) / r["cycles"].mean())
    print(f"{args.scene}: {len(r['pt'])} interior texels, path-traced noise {noise_pt:.1%} per texel, "
          f"Cycles pair noise {noise_cycles:.1%}")
    for label in ("cycles", "pdic"):
        rms, bias = agreement(r[label], r["pt"])
        print(f"  {label:7s} against path tracing: {rms:.1%} relative RMS (noise included), bias {bias:+.1%}")


if __name__ == "__main__":
    main()
