"""A third opinion: brute-force diffuse path tracing at light-map texels, independent of both bakers.

    .venv/bin/python bench/path_referee.py --scene occluded [--texels 160] [--paths 4000]
    .venv/bin/python bench/path_referee.py --scene occluded --point=4.62,-0.08,0.1995/0,0,-1

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


def agreement(test: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(relative RMS difference, mean bias) of ``test`` against ``truth`` (texels x 3)."""
    return (float(np.sqrt(np.mean((test - truth) ** 2)) / max(truth.mean(), 1e-30)),
            float(test.sum() / max(truth.sum(), 1e-30) - 1.0))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="occluded", help="a converged-bench scene: cornell, occluded, sponza")
    ap.add_argument("--texels", type=int, default=160)
    ap.add_argument("--paths", type=int, default=4000, help="paths per texel (or per point)")
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
