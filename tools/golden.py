"""Golden outputs of the core bake: record them, or check a new run against them bit for bit.

    .venv/bin/python tools/golden.py OUT.npz          # record
    .venv/bin/python tools/golden.py --check OLD.npz  # bake again, compare, exit 1 on any difference

A refactor of ``core/`` must leave every light map identical to the bit. This bakes a fixed set
of seeded scenes and settings with the core (extraction through the add-on, as the bench does):
the three sample blends at Preview and Final, the generated occluded building and a small Sponza
at Final, with ``reuse_photon_paths`` and ``gradients`` on and off, and with a :class:`BakeCache`
(a re-bake from the cache must give the same maps). Every light map (RGBA, direct, indirect) and
every statistics counter (not the timings) is stored under ``<config>/<target>/<what>``.
About 6 CPU-minutes (Sponza takes most; 7 minutes wall on a quiet 2-core machine, over 20 when
six jobs share it; ``--only`` runs a subset); the unwraps are kept in a cache folder (``--work``,
default /tmp/pdic_golden) so re-runs skip them.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import pdic_bootstrap  # noqa: E402

pdic_bootstrap.load()

import bpy  # noqa: E402

from pdic import pdic_addon  # noqa: E402
from pdic.bench import scenes as bench_scenes  # noqa: E402
from pdic.core.bake_cache import BakeCache  # noqa: E402
from pdic.core.executor import Executor  # noqa: E402
from pdic.core.pipeline import bake  # noqa: E402
from pdic.core.settings import preset  # noqa: E402

SAMPLE_RES = 32
SAMPLE_PHOTONS = 20_000
SPONZA_PHOTONS = 100_000
"""200k photons made the run 7 minutes on 2 cores (Sponza Final alone 141 s, without reuse 207 s)."""


def sample_scene(name: str):
    objects = bench_scenes.load_cornell(name)
    return bench_scenes.extract_lightmap_uv(objects, SAMPLE_RES)


def generated_scene(name: str, work: Path, **settings):
    objects = bench_scenes.load_sponza() if name == "sponza" else bench_scenes.load_occluded()
    bpy.context.view_layer.update()  # after a sample blend was open, the new objects reach the view layer here
    _, scene = bench_scenes.prepare(objects, preset("FINAL", min_resolution=8, **settings), work / name)
    return scene


def configs():
    """(scene name, loader, [(config name, settings, cache group or None)])."""
    small = dict(photons=SAMPLE_PHOTONS, direct_samples=4)
    out = []
    for name in ("cornell_point", "cornell_area", "textured_room"):
        runs = [("preview", preset("PREVIEW", **small), None), ("final", preset("FINAL", **small), None)]
        if name == "cornell_point":
            runs += [("final_noreuse", preset("FINAL", reuse_photon_paths=False, **small), None),
                     ("final_nogradients", preset("FINAL", gradients=False, **small), None),
                     ("preview_nogradients", preset("PREVIEW", gradients=False, **small), None),
                     # with a BakeCache: fill it, re-bake from it, then change what only later stages read
                     ("cached_fill", preset("FINAL", **small), "c"),
                     ("cached_again", preset("FINAL", **small), "c"),
                     ("cached_nogradients", preset("FINAL", gradients=False, **small), "c"),
                     ("cached_preview", preset("PREVIEW", **small), "c")]
        if name == "cornell_area":
            runs += [("final_noreuse", preset("FINAL", reuse_photon_paths=False, **small), None)]
        out.append((name, lambda work, n=name: sample_scene(n), runs))
    building = dict(texel_density=2.0)
    out.append(("building", lambda work: generated_scene("building", work, **building), [
        ("final", preset("FINAL", photons=60_000, direct_samples=4, min_resolution=8, **building), None),
        ("final_noreuse", preset("FINAL", photons=60_000, direct_samples=4, reuse_photon_paths=False,
                                 min_resolution=8, **building), None),
        ("cached_fill", preset("PREVIEW", photons=60_000, direct_samples=4, min_resolution=8, **building), "b"),
        ("cached_again", preset("PREVIEW", photons=60_000, direct_samples=4, min_resolution=8, **building), "b"),
    ]))
    sponza = dict(texel_density=2.0, direct_samples=2, min_resolution=8, photons=SPONZA_PHOTONS)
    out.append(("sponza", lambda work: generated_scene("sponza", work, texel_density=2.0), [
        ("final", preset("FINAL", **sponza), None),
        ("final_noreuse_nogradients", preset("FINAL", reuse_photon_paths=False, gradients=False, **sponza), None),
    ]))
    return out


def run(work: Path, only: set | None = None) -> dict:
    """Bake every config: {key: array}; counters as a JSON string array per config."""
    pdic_addon.register()
    arrays = {}
    with Executor(2) as executor:
        for scene_name, load, runs in configs():
            if only and scene_name not in only:
                continue
            start = time.perf_counter()
            scene = load(work)
            stores: dict = {}
            for config, settings, group in runs:
                settings = replace(settings, threads=2)
                store = stores.setdefault(group, BakeCache()) if group else None
                t0 = time.perf_counter()
                result = bake(scene, settings, executor=executor, cache=store)
                prefix = f"{scene_name}/{config}"
                for target in sorted(result.lightmaps):
                    arrays[f"{prefix}/{target}/rgba"] = result.lightmaps[target]
                    arrays[f"{prefix}/{target}/direct"] = result.direct[target]
                    arrays[f"{prefix}/{target}/indirect"] = result.indirect[target]
                arrays[f"{prefix}/counters"] = np.array(json.dumps(result.stats["counters"], sort_keys=True))
                print(f"  {prefix}: {len(result.lightmaps)} maps, {time.perf_counter() - t0:.1f} s", flush=True)
            print(f"{scene_name}: {time.perf_counter() - start:.1f} s", flush=True)
    pdic_addon.unregister()
    return arrays


TIMING_COUNTERS = ("embree_seconds_", "embree_share_")
"""Counters that are times, not results: never compared."""


def compare(old: dict, new: dict) -> list[str]:
    """Human-readable differences between two golden runs (empty when identical to the bit)."""
    problems = []
    for key in sorted(set(old) | set(new)):
        if key not in new or key not in old:
            problems.append(f"{key}: only in the {'old' if key in old else 'new'} run")
            continue
        a, b = old[key], new[key]
        if key.endswith("/counters"):
            ca, cb = json.loads(str(a)), json.loads(str(b))
            for c in sorted(set(ca) | set(cb)):
                if c.startswith(TIMING_COUNTERS):
                    continue
                if ca.get(c) != cb.get(c):
                    problems.append(f"{key}: {c} {ca.get(c)} -> {cb.get(c)}")
        elif a.shape != b.shape or a.dtype != b.dtype:
            problems.append(f"{key}: {a.dtype}{a.shape} -> {b.dtype}{b.shape}")
        elif a.tobytes() != b.tobytes():
            diff = np.abs(a.astype(np.float64) - b.astype(np.float64))
            problems.append(f"{key}: max abs diff {diff.max():.3g}, {int((diff > 0).sum())} values differ")
    return problems


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out", nargs="?", help="record the golden outputs into this .npz")
    parser.add_argument("--check", metavar="FILE", help="compare a new run with this .npz bit for bit")
    parser.add_argument("--only", nargs="*", help="scene names to run (cornell_point, ..., building, sponza)")
    parser.add_argument("--work", default="/tmp/pdic_golden", help="unwrap cache folder")
    args = parser.parse_args(argv)
    if not args.out and not args.check:
        parser.error("give OUT.npz to record or --check FILE")
    start = time.perf_counter()
    arrays = run(Path(args.work), set(args.only) if args.only else None)
    print(f"total {time.perf_counter() - start:.1f} s, {len(arrays)} arrays")
    if args.out:
        np.savez_compressed(args.out, **arrays)
        print(f"recorded {args.out}")
    if args.check:
        with np.load(args.check) as f:
            old = {k: f[k] for k in f.files if not args.only or k.split("/")[0] in args.only}
        problems = compare(old, arrays)
        for p in problems:
            print("DIFF", p)
        print("identical to the bit" if not problems else f"{len(problems)} differences")
        return 1 if problems else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
