"""Converged Cycles references: 64 diffuse bounces, sample clamping off, adaptive sampling off.

    .venv/bin/python bench/converged_references.py [--only cornell,sponza,occluded] [--scenes-only]

Each reference is a pair of Cycles INDIRECT bakes with seeds 1 and 2 (``spp`` samples each),
so its own noise is known: rms(b1 - b2) / sqrt 2 per bake, and a comparison against the pair
subtracts it (bench/run.py ``noise_corrected_error``). Written to bench/references/:

- ``cornell_point_64_{2 spp}_64_INDIRECT.npz`` and ``cornell_area_64_{2 spp}_64_INDIRECT.npz`` (``--only
  cornell_area``): the Cornell sample blends' ``LightMap`` at 64^2 per object, the pair averaged (the
  format of tests/cycles_reference.py ``reference``), plus the pair itself (``a_*``, ``b_*``) and
  ``noise`` (relative, of the average).
- ``{scene}_one_d{density}_{spp}x2_64_INDIRECT.npz``: Sponza joined into one object, and the
  occluded building (bench/scenes.py), in the add-on's ``PDIC_Lightmap`` at ``density`` texels/m:
  ``a_*``, ``b_*``, ``cov_*``, ``seconds``, ``noise`` (relative, of one bake). The core scene the
  add-on extracted (same UVs) is pickled to bench/results/converged/{scene}.pkl for PDIC bakes.
  Their maps are sized from the surface area, as the add-on did up to session 16: the charts
  fitted into that side hold fewer texels per metre than ``density`` (the building's walls 0.94).
- ``occluded_held_one_d4_...``, ``sponza_held_one_d4_...``: the building and Sponza as the add-on
  bakes them now at 4 texels/m, their maps grown until the charts hold that density (260^2 instead
  of 164^2, 732^2 instead of 696^2).

The references hold the UVs of the unwrap that baked them: a change to the unwrap (core/unwrap.py,
core/xatlas_charts.py) needs them baked again (session 52 did, after 4b285dc's packing change had left all
four one-object pairs on charts the scenes no longer have).
"""
from __future__ import annotations

import argparse
import pickle
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
import pdic_bootstrap  # noqa: E402

pdic_bootstrap.load()
import bpy  # noqa: E402

from pdic import pdic_addon  # noqa: E402
from pdic.bench import run as bench_run  # noqa: E402
from pdic.bench import scenes as bench_scenes  # noqa: E402
from pdic.core.settings import preset  # noqa: E402

REFERENCES = ROOT / "bench" / "references"
SCENES = ROOT / "bench" / "results" / "converged"
BOUNCES = 64
"""Cycles diffuse (and total) bounces: converged (Sponza warms up to 16 diffuse bounces)."""
PLAN = {"cornell": dict(spp=1024, density=None), "cornell_area": dict(spp=1024, density=None),
        "sponza": dict(spp=512, density=4.0), "occluded": dict(spp=2048, density=4.0),
        "occluded_held": dict(spp=1024, density=4.0),
        "sponza_held": dict(spp=512, density=4.0)}
"""Samples per bake of each pair (Cornell: 2 x 1024 on a machine shared by six jobs) and texel density
(texels/m); a ``_held`` scene's map holds the density (the add-on's own sizing), the others' are
sized from the surface area."""


def seed_pair(objects, uv: str, sizes: dict, spp: int) -> tuple[list, float]:
    """Two Cycles INDIRECT bakes (seeds 1, 2) of ``objects`` ({name: (w, h)}); (pair, seconds)."""
    from tests.cycles_reference import cycles_bake_full

    by_size: dict = {}
    for name, size in sizes.items():
        by_size.setdefault(size, []).append(name)
    named = {o.name: o for o in objects}
    pair, t = [], time.perf_counter()
    for seed in (1, 2):
        images, coverage = {}, {}
        for (w, h), names in by_size.items():
            b = cycles_bake_full([named[n] for n in names], uv, w, h, {"INDIRECT"}, spp, seed=seed,
                                 diffuse_bounces=BOUNCES, clamp_indirect=0.0)
            images.update(b.images)
            coverage.update(b.coverage)
        pair.append(dict(images=images, coverage=coverage))
    return pair, time.perf_counter() - t


def pair_noise(pair) -> float:
    """Relative RMS noise of one bake of the pair: rms(b1 - b2) / sqrt 2 / mean."""
    a, b = pair
    d = np.concatenate([(a["images"][n] - b["images"][n])[a["coverage"][n]].ravel() for n in a["images"]])
    m = np.concatenate([(a["images"][n] + b["images"][n])[a["coverage"][n]].ravel() for n in a["images"]]).mean() / 2
    return float(np.sqrt(np.mean(d ** 2) / 2.0) / max(m, 1e-30))


def save_pair(path: Path, pair, seconds: float, averaged: bool) -> float:
    noise = pair_noise(pair)
    a, b = pair
    arrays = {f"a_{n}": a["images"][n] for n in a["images"]}
    arrays.update({f"b_{n}": b["images"][n] for n in b["images"]})
    arrays.update({f"cov_{n}": a["coverage"][n] & b["coverage"][n] for n in a["images"]})
    if averaged:  # tests/cycles_reference.py ``reference`` reads img_* as the reference
        arrays.update({f"img_{n}": 0.5 * (a["images"][n] + b["images"][n]) for n in a["images"]})
        noise /= np.sqrt(2.0)
    REFERENCES.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, seconds=seconds, noise=noise, bounces=BOUNCES, **arrays)
    print(f"{path.name}: {seconds:.0f} s, relative noise {noise:.4f}", flush=True)
    return noise


def cornell(spp: int, blend: str = "cornell_point") -> None:
    """A Cornell sample blend (``cornell_point``: the point light under the ceiling; ``cornell_area``: the
    ceiling's area light) at 64^2 per object in its ``LightMap`` UVs."""
    objects = bench_scenes.load_cornell(blend)
    sizes = {o.name: (64, 64) for o in objects}
    pair, seconds = seed_pair(objects, "LightMap", sizes, spp)
    save_pair(REFERENCES / f"{blend}_64_{2 * spp}_{BOUNCES}_INDIRECT.npz", pair, seconds, averaged=True)


def join(objects: list) -> list:
    """Join mesh objects into the first one (Sponza as imported into one object)."""
    with bpy.context.temp_override(active_object=objects[0], selected_editable_objects=objects,
                                   selected_objects=objects):
        bpy.ops.object.join()
    return [o for o in bpy.context.scene.objects if o.type == "MESH"]


def one_object_scene(name: str, density: float, cache_dir: Path) -> tuple[list, object]:
    """Sponza or the occluded building (``name``) joined into one object and unwrapped as the references
    were: (the Blender objects, the core scene the add-on extracts, its UVs those of the reference)."""
    objects = bench_scenes.load_sponza() if name.startswith("sponza") else bench_scenes.load_occluded()
    objects = join(objects)
    settings = preset("FINAL", texel_density=density, min_resolution=32)
    _, scene = bench_scenes.prepare(objects, settings, cache_dir, area_sized=not name.endswith("_held"))
    return objects, scene


def one_object(name: str, spp: int, density: float, scenes_only: bool = False, tag: str = "") -> None:
    objects, scene = one_object_scene(name, density, SCENES / "cache" / name)
    SCENES.mkdir(parents=True, exist_ok=True)
    (SCENES / f"{name}{tag}.pkl").write_bytes(pickle.dumps(scene))
    from pdic.pdic_addon.uvmaps import LIGHTMAP_UV

    sizes = {t.name: (t.width, t.height) for t in scene.targets}
    print(name, "targets", sizes, "triangles", scene.geometry.count, flush=True)
    if scenes_only:
        return
    pair, seconds = seed_pair(objects, LIGHTMAP_UV, sizes, spp)
    save_pair(REFERENCES / f"{name}_one_d{density:g}_{spp}x2_{BOUNCES}{tag}_INDIRECT.npz", pair, seconds,
              averaged=False)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", default="cornell,sponza,occluded")
    ap.add_argument("--tag", default="", help="appended to the one-object references' and scenes' file names "
                    "(e.g. _b52 for bakes by another Blender; bench/convergence.py --tag reads them)")
    ap.add_argument("--scenes-only", action="store_true",
                    help="write only the one-object core scenes (the committed references' UVs), no Cycles bake")
    args = ap.parse_args(argv)
    pdic_addon.register()
    for name in [s.strip() for s in args.only.split(",") if s.strip()]:
        plan = PLAN[name]
        if name in bench_run.CORNELL_BLENDS:
            if not args.scenes_only:
                cornell(plan["spp"], bench_run.CORNELL_BLENDS[name])
        else:
            one_object(name, plan["spp"], plan["density"], args.scenes_only, args.tag)


if __name__ == "__main__":
    main()
