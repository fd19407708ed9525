"""Cathedral (tests/cathedral.py): PDIC's direct light against Cycles' Diffuse Direct bake, texel by texel.

    .venv/bin/python bench/cathedral_direct.py [--detail 0.3] [--res 512] [--spp 16] [--examples 3]

One mesh object (the generated cathedral, one Diffuse BSDF material), two hard point lights in
the nave, black world. PDIC bakes direct light only through the add-on's
``BakeJob``; Cycles bakes Diffuse Direct (no Color, adaptive sampling off) into the
same ``PDIC_Lightmap`` UVs at the resolution PDIC chose. Compared on texels Cycles
baked whose centre lies on a triangle (``baked``); ``flat`` = ``baked`` texels away
from shadow edges (tests/test_direct_vs_cycles.flat_mask: 3x3 neighbourhood baked,
Cycles luminance varying by < 10 % of the centre there, or 0 throughout).

Prints the texel counts, the shares lit by one and dark in the other, the share of
flat texels within 2 %, PDIC's mean and relative RMS error over lit texels against the mean of
two Cycles seeds (and their own half-difference), and for the wrong texels their position, geometric normal
and the part of the cathedral they lie on.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
import pdic_bootstrap  # noqa: E402

pdic_bootstrap.load()
import bpy  # noqa: E402

import cycles_reference as cr  # noqa: E402
from test_cathedral_direct_vs_cycles import DARK, LIGHTS, WITHIN, build_cathedral_scene, direct_comparison  # noqa: E402
from test_direct_vs_cycles import bake_pdic  # noqa: E402

from pdic import pdic_addon  # noqa: E402
from pdic.core.settings import Deviations  # noqa: E402
from pdic.pdic_addon import writeback  # noqa: E402
from pdic.pdic_addon.uvmaps import LIGHTMAP_UV  # noqa: E402


LIT = 0.01
"""E/pi above which a texel counts as lit for the mean and RMS errors (lit texels here: 0.01 to 10)."""


def build(detail: float):
    """A factory-fresh file with the cathedral as one object and the test's two lights; returns the object."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return build_cathedral_scene(bpy, detail)


def prepare(out: str, detail: float):
    """(the output folder, made; the cathedral object in a fresh file with the add-on registered)."""
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    pdic_addon.register()
    return folder, build(detail)


def texel_geometry(ob, rows, cols, width, height):
    """World position and geometric normal (n, 3) and polygon index (n,) of texel centres, via
    the evaluated triangles of ``PDIC_Lightmap``; the first triangle containing each centre."""
    me = ob.data
    me.calc_loop_triangles()
    tris = me.loop_triangles
    n = len(tris)
    loops = np.empty(n * 3, np.int64)
    tris.foreach_get("loops", loops)
    verts = np.empty(n * 3, np.int64)
    tris.foreach_get("vertices", verts)
    poly = np.empty(n, np.int64)
    tris.foreach_get("polygon_index", poly)
    uv = np.empty(len(me.loops) * 2, np.float64)
    me.uv_layers[LIGHTMAP_UV].data.foreach_get("uv", uv)
    uv = uv.reshape(-1, 2)[loops].reshape(n, 3, 2) * [width, height]
    co = np.empty(len(me.vertices) * 3, np.float64)
    me.vertices.foreach_get("co", co)
    P = co.reshape(-1, 3)[verts].reshape(n, 3, 3)
    out_p = np.full((len(rows), 3), np.nan)
    out_n = np.full((len(rows), 3), np.nan)
    out_f = np.full(len(rows), -1)
    out_k = np.zeros(len(rows), int)  # how many triangles contain the centre
    lo, hi = uv.min(axis=1), uv.max(axis=1)
    for i, (r, c) in enumerate(zip(rows, cols)):
        q = np.array([c + 0.5, r + 0.5])
        cand = np.nonzero((lo <= q).all(1) & (hi >= q).all(1))[0]
        for t in cand:
            a, b, d = uv[t]
            m = np.array([b - a, d - a]).T
            if abs(np.linalg.det(m)) < 1e-12:
                continue
            w1, w2 = np.linalg.solve(m, q - a)
            if w1 >= 0 and w2 >= 0 and w1 + w2 <= 1:
                out_k[i] += 1
                if out_f[i] < 0:
                    p0, p1, p2 = P[t]
                    out_p[i] = p0 + w1 * (p1 - p0) + w2 * (p2 - p0)
                    nn = np.cross(p1 - p0, p2 - p0)
                    out_n[i] = nn / np.linalg.norm(nn)
                    out_f[i] = poly[t]
    return out_p, out_n, out_f, out_k


def part(p, nrm) -> str:
    """Which part of the cathedral a point lies on (from tests/cathedral.py's layout)."""
    x, y, z = p
    ay = abs(y)
    if z < 1e-3 and abs(nrm[2]) > 0.99 and x < 37.0:
        return "floor"
    if x > 36.9 and ay <= 3.01 and z <= 1.09:
        return "stairs"
    if x > 40.0 - 1e-6 and z <= 12.0 + 8.1:
        return "apse dome" if z > 12.0 + 1e-6 else "apse wall"
    if 7.99 <= ay <= 8.81 or (7.5 <= ay <= 8.01 and 6.99 <= z <= 7.49):
        if z >= 12.0 - 1e-6:
            return "wall top / parapet"
        if 6.99 <= z <= 7.49 and ay < 8.01:
            return "stacked mouldings"
        return "wall outside" if ay > 8.4 else "wall inside"
    if 7.85 <= ay <= 8.0 and 7.8 <= z <= 10.4:
        return "tracery"
    if 3.4 <= ay <= 4.6:
        if z <= 0.61:
            return "column base"
        if z <= 6.0:
            return "column shaft"
        if z <= 6.76 and (x % 4.0 < 0.8 or x % 4.0 > 3.2):
            return "capital / rosette"
        return "arch"
    return "other"


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--detail", type=float, default=0.3)
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--examples", type=int, default=3)
    ap.add_argument("--no-footprint", action="store_true", help="bake without the direct-footprint deviation")
    ap.add_argument("--threads", type=int, default=0, help="PDIC worker threads (1 for CPU-second comparisons)")
    ap.add_argument("--out", default="/tmp/pdic_cathedral_direct")
    args = ap.parse_args(argv)
    folder, ob = prepare(args.out, args.detail)
    t, cpu = time.perf_counter(), time.process_time()
    job, _ = bake_pdic(bpy, folder, 1, args.res, threads=args.threads,
                       deviations=Deviations(direct_footprint=not args.no_footprint))
    pdic_s, pdic_cpu = time.perf_counter() - t, time.process_time() - cpu
    counters = job.result.stats.get("counters", {})
    print(f"PDIC: {pdic_cpu:.1f} CPU s (whole BakeJob, unwrap included), direct stage "
          f"{job.result.stats.get('seconds', {}).get('direct', float('nan')):.2f} s wall; shadow rays "
          f"{counters.get('shadow_rays', 0):,} + footprint {counters.get('direct_footprint_shadow_rays', 0):,} on "
          f"{counters.get('direct_footprint_texels', 0):,} texels")
    P = job.result.as_cycles(ob.name)  # Cycles' convention (the light map fills buried texels)
    H, W = P.shape[:2]
    writeback.set_shading([ob], baked=False)
    t = time.perf_counter()
    ref = cr.cycles_bake_full([ob], LIGHTMAP_UV, W, H, {"DIRECT"}, args.spp)
    cyc_s = time.perf_counter() - t
    C = ref.images[ob.name]
    second = cr.cycles_bake_full([ob], LIGHTMAP_UV, W, H, {"DIRECT"}, args.spp, seed=1).images[ob.name]
    baked = ref.coverage[ob.name] & job.result.centre_inside[ob.name]
    m = direct_comparison(P, C, baked)
    flat = m["flat_mask"]
    np.savez_compressed(folder / f"d{args.detail}_{W}.npz", P=P, C=C, baked=baked, flat=flat)

    lp, lc = P.mean(axis=2), C.mean(axis=2)
    n = int(baked.sum())
    pdic_only = baked & (lp > DARK) & (lc <= DARK)
    cycles_only = baked & (lc > DARK) & (lp <= DARK)
    rel = np.abs(lp - lc) / np.maximum(lc, DARK)
    ok = (rel <= WITHIN) | ((lp <= DARK) & (lc <= DARK))
    ntri = sum(len(p.vertices) - 2 for p in ob.data.polygons)
    print(f"detail {args.detail}: {ntri} triangles, map {W}x{H}; PDIC {pdic_s:.1f} s, Cycles {args.spp} spp "
          f"{cyc_s:.1f} s; warnings {job.report.warnings}")
    print(f"texels: centre inside {int(job.result.centre_inside[ob.name].sum())}, Cycles-covered "
          f"{int(ref.coverage[ob.name].sum())}, baked (both) {n}, flat {int(flat.sum())}")
    print(f"lit in PDIC, dark in Cycles: {int(pdic_only.sum())} ({pdic_only.sum() / n:.2%}); "
          f"lit in Cycles, dark in PDIC: {int(cycles_only.sum())} ({cycles_only.sum() / n:.2%})")
    print(f"within {WITHIN:.0%}: flat {ok[flat].mean():.2%}, baked {ok[baked].mean():.2%}; "
          f"flat off > 90 %: {(rel[flat] > 0.9).sum()}; sum|P-C|/sumC flat "
          f"{np.abs(P - C)[flat].sum() / C[flat].sum():.4f}, baked {np.abs(P - C)[baked].sum() / C[baked].sum():.4f}")

    lc2 = second.mean(axis=2)
    rel2 = np.abs(lc2 - lc) / np.maximum(lc, DARK)
    both = (lc + lc2) / 2  # the two seeds' mean
    lit = baked & (both > LIT)
    print(f"lit texels (the seeds' mean E/pi > {LIT}): {int(lit.sum())}; PDIC against the seeds' mean: mean "
          f"|P/C - 1| {np.mean(np.abs(lp[lit] / both[lit] - 1)):.2%}, relative RMS "
          f"{np.sqrt(np.sum((lp - both)[lit] ** 2) / np.sum(both[lit] ** 2)):.2%}; the seeds' half-difference "
          f"{np.mean(np.abs(lc2 - lc)[lit] / 2 / both[lit]):.2%}")
    print(f"Cycles seed 0 vs seed 1 within {WITHIN:.0%}: flat {((rel2 <= WITHIN) | (lc <= DARK))[flat].mean():.2%}; "
          f"noise sum|C1-C0|/sumC/sqrt2 flat {np.abs(second - C)[flat].sum() / C[flat].sum() / np.sqrt(2):.4f}")
    wrong_flat = flat & ~ok
    classes = {"lit only in PDIC": pdic_only, "lit only in Cycles": cycles_only,
               "flat, off > 2 %": wrong_flat & ~pdic_only & ~cycles_only, "flat, off > 90 %": flat & (rel > 0.9),
               "centre inside a triangle, not baked by Cycles": job.result.centre_inside[ob.name] & ~ref.coverage[ob.name]}
    for label, mask in classes.items():
        rows, cols = np.nonzero(mask)
        if len(rows) == 0:
            print(f"{label}: none")
            continue
        pos, nrm, face, inside = texel_geometry(ob, rows, cols, W, H)
        parts = {}
        for p, nn in zip(pos, nrm):
            name = part(p, nn) if np.isfinite(p).all() else "no triangle"
            parts[name] = parts.get(name, 0) + 1
        # chart border: a 3x3 neighbour is not baked
        pad = np.pad(baked, 1)
        border = ~np.stack([pad[rows + dy, cols + dx] for dy in range(3) for dx in range(3)]).all(axis=0)
        lit = np.pad(lc > DARK, 1)
        near_lit = np.stack([lit[rows + dy, cols + dx] for dy in range(3) for dx in range(3)]).any(axis=0)
        to_lights = np.array(LIGHTS)[None, :, :3] - pos[:, None, :]
        facing_away = (np.einsum("tlk,tk->tl", to_lights, nrm) <= 0).all(axis=1)
        print(f"{label}: {len(rows)} texels; on chart borders {border.mean():.0%}; a Cycles-lit texel within 1 "
              f"texel {near_lit.mean():.0%}; centre's facet faces away from both lights {facing_away.mean():.0%}; "
              f"centre in > 1 triangle "
              f"{(inside > 1).sum()}; parts {dict(sorted(parts.items(), key=lambda kv: -kv[1]))}")
        for i in np.linspace(0, len(rows) - 1, min(args.examples, len(rows))).astype(int):
            to_light = np.array(LIGHTS)[:, :3] - pos[i]
            cos = to_light @ nrm[i] / np.linalg.norm(to_light, axis=1)
            print(f"   texel ({rows[i]}, {cols[i]}) at {np.round(pos[i], 3)} n {np.round(nrm[i], 2)} n.l {np.round(cos, 2)} polygon "
                  f"{face[i]}: PDIC {np.round(P[rows[i], cols[i]], 4)} Cycles {np.round(C[rows[i], cols[i]], 4)}")
    pdic_addon.unregister()


if __name__ == "__main__":
    main()
