"""Cycles + OIDN, the baker users already have, against PDIC at equal error (issue #12, items 3-4).

    bash tools/bench.sh --only competitors                                  # Cornell, occluded, Sponza 16/m
    bash tools/bench.sh --only competitors --competitors cornell256,sponza2048
    .venv/bin/python -m bench.competitors --scenes cornell256 --quick       # without bench.run

Every scene is ONE object (as a light-map user bakes it) unwrapped by the add-on into
``PDIC_Lightmap``; Cycles bakes the same UVs. Per scene:

* Cycles Diffuse bakes (no Color) at a ladder of samples, adaptive sampling off, 32 diffuse
  bounces, no clamping, a 16-texel margin (the denoiser then sees no black chart borders),
  seed 0; once Direct+Indirect and once Indirect only. Each bake is denoised by OIDN three
  ways: ``RT`` (HDR colour only), ``RT+aux`` (albedo 1 - what a Diffuse bake without Color
  has - and the texels' shading normals, dilated into the margin, marked clean) and
  ``RTLightmap`` (colour only; it takes no auxiliary images).
* The reference: two bakes per pass set at a higher sample count with seeds 1 and 2 (cached
  in ``bench/results/competitors/<scene>/`` by spp, seed and passes, since only its noise
  matters and not its time); every error is noise-corrected against the pair
  (``bench.run.noise_corrected_error``), so the pair need not be converged.
* PDIC Final and Preview defaults on the same core scene.
* Errors on the texels both bakers bake (the same texels for all): their centre lies on a triangle
  by PDIC's rasteriser (``centre_inside``) and Cycles bakes them (:func:`cycles_coverage`, a
  margin-0 bake). xatlas packs charts with their corners on texel centres, so a chart's outer row of
  centres lies exactly on its edge, where the two rasterisers decide differently; a texel Cycles
  does not bake holds its margin's fill from a neighbouring face, no reference for PDIC's value
  (the occluded building: 3.2 % of PDIC's texels, 28 % error per texel over all of them, 2.3 %
  without). Per texel and on 8x8-texel block means, direct+indirect and indirect only.
* Wall seconds and CPU seconds (``time.process_time``: all threads of this process; Cycles
  runs in-process through bpy) of every bake and every denoise; both bakers use 2 threads.
* Equal-error speed-ups (Cycles' CPU seconds interpolated log-log on its ladder at PDIC's
  error) and crops around a contact shadow, saved for ``bench/report.py`` to draw.

PDIC's time is its core bake (the UVs are shared, so the unwrap is not charged to either);
Cycles' time is the ``bpy.ops.object.bake`` call (scene sync included) plus the denoise.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

PASS_SETS = {"all": frozenset({"DIRECT", "INDIRECT"}), "indirect": frozenset({"INDIRECT"})}
"""Cycles pass filters of the two error kinds: direct+indirect and indirect only."""
CYCLES_BOUNCES = 32
"""Cycles' diffuse (and max) bounces: enough that the reference misses no visible light."""
MARGIN = 16
"""Cycles' bake margin in texels, as light-map users set it before denoising."""
BLOCK = 8
"""Block size (texels) of the block error: a denoiser trades noise for blur, blocks forgive blur."""
LADDER_SEED = 0
REFERENCE_SEEDS = (1, 2)
DENOISERS = ("RT", "RT+aux", "RTLightmap")
CROP = 40
"""Side of a crop (texels) drawn around a contact shadow."""


@dataclass(frozen=True)
class SceneSpec:
    """One competitor scene: how to load it, its light-map size and sample counts.

    resolution : fixed light-map side in texels, or 0 to take it from ``texel_density`` and the
        surface area, as the add-on did up to session 16 (the charts fitted into that side, not the
        side grown to hold them at the density): the scenes stay the ones every row was measured on.
    ladder : Cycles samples per texel of the measured bakes.
    reference_spp : samples of each bake of the seed pair that serves as the reference.
    crop_world : world point (m) the crops centre on (the texel nearest to it).
    optional : run only when named explicitly (long runs).
    """

    label: str
    loader: str
    resolution: int
    texel_density: float
    ladder: tuple
    reference_spp: int
    crop_world: tuple
    optional: bool = False


SCENES = {
    # the tall block's base on the floor, front-left corner (contact edge)
    # the floor at the short block's front edge (contact shadow of a block on the floor)
    "cornell256": SceneSpec("Cornell box, 256^2", "cornell", 256, 0.0, (4, 16, 64, 256), 512,
                            (0.1, -0.23, 0.0)),
    # room 2 (lit only through doorways): the floor at a column's base
    "occluded": SceneSpec("Occluded building, 16 texels/m", "occluded", 0, 16.0, (4, 16, 64), 64,
                          (7.5, 1.2, 0.0)),
    # the building with its two lamps replaced by 64 of the same total power (deviation light-selection)
    "occluded64": SceneSpec("Occluded building with 64 lamps, 16 texels/m", "occluded_lamps", 0, 16.0, (4, 16, 64),
                            64, (7.5, 1.2, 0.0), optional=True),
    # the building lit by 16 ceiling panels (area lights) of the same total power (deviation light-budget)
    "occluded16area": SceneSpec("Occluded building with 16 ceiling panels, 16 texels/m", "occluded_panels", 0, 16.0,
                                (4, 16, 64), 64, (7.5, 1.2, 0.0), optional=True),
    # the floor at the base of an arcade column beside the east light
    "sponza16": SceneSpec("Sponza, 16 texels/m", "sponza", 0, 16.0, (4, 16, 64), 128, (6.5, 2.3, 0.09)),
    "sponza8": SceneSpec("Sponza, 8 texels/m", "sponza", 0, 8.0, (4, 16, 64), 64, (6.5, 2.3, 0.09), optional=True),
    # 64-spp references: 2 x 128 spp of both kinds over 2.9 M texels would take Cycles ~50 min here
    "sponza2048": SceneSpec("Sponza, 2048^2", "sponza", 2048, 0.0, (4, 16, 64), 64, (6.5, 2.3, 0.09),
                            optional=True),
}
DEFAULT_SCENES = tuple(k for k, s in SCENES.items() if not s.optional)
QUICK = dict(resolution=64, ladder=(4, 16), reference_spp=64)
"""A --quick run: Cornell only, small map and ladder (checks the plumbing, not the numbers)."""


def log(*a):
    print(*a, flush=True)


def clocked(fn, *args, **kw):
    """(fn's result, wall seconds, CPU seconds of the whole process)."""
    wall, cpu = time.perf_counter(), time.process_time()
    out = fn(*args, **kw)
    return out, time.perf_counter() - wall, time.process_time() - cpu


# --------------------------------------------------------------------------- errors
def pad_to_blocks(image: np.ndarray, factor: int) -> np.ndarray:
    """Zero-pad the first two axes of ``image`` up to multiples of ``factor``."""
    h, w = image.shape[:2]
    pad = [(0, -h % factor), (0, -w % factor)] + [(0, 0)] * (image.ndim - 2)
    return np.pad(image, pad)


def block_counts(mask: np.ndarray, factor: int = BLOCK) -> np.ndarray:
    """(H/f, W/f) int: the texels of ``mask`` (H, W) bool each f x f block holds (the map zero-padded)."""
    m = pad_to_blocks(mask, factor)
    return m.reshape(m.shape[0] // factor, factor, m.shape[1] // factor, factor).sum(axis=(1, 3))


def block_means(image: np.ndarray, mask: np.ndarray, factor: int = BLOCK):
    """(block means (H/f, W/f, C) of the masked texels, blocks holding any masked texel)."""
    from pdic.bench.run import block_average

    image, mask = pad_to_blocks(image, factor), pad_to_blocks(mask, factor)
    blocks = mask.reshape(mask.shape[0] // factor, factor, mask.shape[1] // factor, factor).any(axis=(1, 3))
    return block_average(image, mask, factor), blocks


BLOCK_OFF = 0.20
"""A block is off when its mean differs from the reference's by more than this (issue #11's bound)."""
BLOCK_LIT = 0.05
"""Blocks whose reference mean is below this fraction of the map's mean block are not judged (noise)."""


def block_differences(test: np.ndarray, reference: np.ndarray, mask: np.ndarray, factor: int = BLOCK
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(|test - reference| / reference of each block's mean luminance (0 where not judged), the judged
    blocks, the test's and the reference's block luminance), over ``mask``'s texels in blocks of
    ``factor``^2: a block is judged when it holds a masked texel and its reference mean is at least
    BLOCK_LIT of the mean block's."""
    (tb, blocks), (rb, _) = block_means(test, mask, factor), block_means(reference, mask, factor)
    lt, lr = tb.mean(axis=2), rb.mean(axis=2)
    judged = blocks & (lr > BLOCK_LIT * (lr[blocks].mean() if blocks.any() else 0.0))
    return np.where(judged, np.abs(lt - lr) / np.maximum(lr, 1e-30), 0.0), judged, lt, lr


METRICS = ("texel", "block", "texel_interior", "block_interior")
"""Error metrics: per texel and on block means, over the centre texels and over interior texels only."""


def errors(test: np.ndarray, pair: tuple, mask: np.ndarray, interior: np.ndarray | None = None,
           block: int = BLOCK) -> dict:
    """Noise-corrected relative RMSE of ``test`` (H, W, 3) against a seed pair, per texel and per block.

    pair : two (H, W, 3) float32 bakes with other seeds than ``test``; mask : (H, W) bool texels compared;
    interior : (H, W) bool, optional: the same again over ``mask & interior`` (``texel_interior``,
    ``block_interior``; ``bench.run.interior_texels``: texels both bakers define alike).
    block : texels per side of the blocks whose means are compared.
    Returns {"texel": float, "block": float} (fractions, 0.02 = 2 %) and "mean_ratio", the
    mean of ``test`` over the pair's (a bias no block size forgives: 0.9 = 10 % too dark).
    """
    from pdic.bench.run import noise_corrected_error

    def corrected(x, a, b, m):
        return noise_corrected_error({"m": x}, {"m": m}, [dict(images={"m": a}, coverage={"m": m}),
                                                          dict(images={"m": b}, coverage={"m": m})])

    out = {"texel": corrected(test, pair[0], pair[1], mask)}
    (x, blocks), (a, _), (b, _) = (block_means(v, mask, block) for v in (test, pair[0], pair[1]))
    out["block"] = corrected(x, a, b, blocks)
    out["mean_ratio"] = float(test[mask].mean() / max(0.5 * (pair[0][mask].mean() + pair[1][mask].mean()), 1e-30))
    if interior is not None:
        inner = errors(test, pair, mask & interior, block=block)
        out["texel_interior"], out["block_interior"] = inner["texel"], inner["block"]
    return out


def _error_fields(err: dict) -> dict:
    """A row's ``error_<metric>`` fields from :func:`errors`' result."""
    return {f"error_{m}": err[m] for m in METRICS if m in err}


# --------------------------------------------------------------------------- scenes
def join(objects: list):
    """Join the mesh objects into one (a light-map user bakes one object); returns it."""
    import bpy

    bpy.ops.object.select_all(action="DESELECT")
    for ob in objects:
        ob.select_set(True)
    bpy.context.view_layer.objects.active = objects[0]
    if len(objects) > 1:
        bpy.ops.object.join()
    return bpy.context.view_layer.objects.active


def load_scene(spec: SceneSpec, work: Path):
    """(the joined Blender object, the add-on's core scene) with ``PDIC_Lightmap`` UVs at the spec's size."""
    import bpy

    from pdic.bench import scenes as bench_scenes
    from pdic.core.settings import preset
    from pdic.pdic_addon.job import BakeJob

    loader = {"cornell": bench_scenes.load_cornell, "sponza": bench_scenes.load_sponza,
              "occluded": bench_scenes.load_occluded, "occluded_lamps": bench_scenes.load_occluded_lamps,
              "occluded_panels": bench_scenes.load_occluded_panels}[spec.loader]
    obj = join(loader())
    settings = preset("FINAL", texel_density=spec.texel_density)
    obj.pdic.resolution = spec.resolution or bench_scenes.area_resolution(obj, settings)
    work.mkdir(parents=True, exist_ok=True)
    job = BakeJob(bpy.context, settings, objects=[obj], output_folder=str(work / "out"), cache_dir=work / "unwrap")
    job.prepare()
    return obj, job.extraction.scene


def texel_geometry(scene):
    """Per texel of the one target: (position (H, W, 3) m, unit shading normal (H, W, 3), centre mask).

    The normal is dilated ``MARGIN`` rings into the gutter, where Cycles' margin put colour.
    """
    from pdic.core import texels as texel_stage
    from pdic.core.dilate import dilate

    points, rasters = texel_stage.lift_texels(scene, 1)
    raster = rasters[0]
    weight = texel_stage.splat(np.ones((len(points), 1)), points, raster)
    p = texel_stage.splat(points.p, points, raster) / np.maximum(weight, 1e-30)
    n = texel_stage.splat(points.n_shading, points, raster)
    n = n / np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-30)
    n, _ = dilate(n.astype(np.float32), weight[..., 0] > 0, MARGIN)
    return p, n, raster.centre_inside


# --------------------------------------------------------------------------- Cycles and OIDN
def set_cycles_threads(threads: int = 2) -> None:
    import bpy

    bpy.context.scene.render.threads_mode = "FIXED"
    bpy.context.scene.render.threads = threads


def cycles_bake(obj, size: tuple, passes: frozenset, spp: int, seed: int) -> dict:
    """One Cycles Diffuse (no Color) bake of ``obj``'s PDIC_Lightmap: image (H, W, 3) and its clocks."""
    from pdic.bench.cycles_reference import cycles_bake_full
    from pdic.pdic_addon.uvmaps import LIGHTMAP_UV

    result, wall, cpu = clocked(cycles_bake_full, [obj], LIGHTMAP_UV, size[0], size[1], passes, spp,
                                seed=seed, margin=MARGIN, diffuse_bounces=CYCLES_BOUNCES)
    return dict(image=result.images[obj.name], wall=wall, cpu=cpu)


def reference_pair(obj, size, passes, spp: int, cache: Path) -> tuple:
    """The two reference bakes (seeds 1, 2) of one pass set, read from ``cache`` when baked before on the
    same light-map UVs and mesh (:func:`layout_key`: a new unwrap must not be judged by old texels)."""
    images = []
    key = layout_key(obj)
    for seed in REFERENCE_SEEDS:
        path = reference_path(cache, passes, size, spp, seed, key)
        if path.exists():
            images.append(np.load(path))
            continue
        bake = cycles_bake(obj, size, passes, spp, seed)
        log("competitors reference", path.name, f"{bake['wall']:.0f} s wall, {bake['cpu']:.0f} s CPU")
        cache.mkdir(parents=True, exist_ok=True)
        np.save(path, bake["image"])
        images.append(bake["image"])
    return tuple(images)


def cycles_coverage(obj, size, cache: Path) -> np.ndarray:
    """(H, W) bool: the texels Cycles bakes itself on ``obj``'s PDIC_Lightmap (a 1-spp direct-light bake
    without margin: its alpha), cached in ``cache`` per :func:`layout_key` as the references are. With a
    margin Cycles fills the texels round each chart from the faces beside it, so its margin-16 bakes say
    nothing of which texels it baked (bench/cornell_direct.py masks its comparison with this too)."""
    from pdic.bench.cycles_reference import cycles_bake_full
    from pdic.pdic_addon.uvmaps import LIGHTMAP_UV

    path = coverage_path(cache, size, layout_key(obj))
    if path.exists():
        return np.load(path)
    coverage = cycles_bake_full([obj], LIGHTMAP_UV, size[0], size[1], {"DIRECT"}, 1, margin=0).coverage[obj.name]
    cache.mkdir(parents=True, exist_ok=True)
    np.save(path, coverage)
    return coverage


def reference_path(cache: Path, passes, size, spp: int, seed: int, key: str) -> Path:
    """Where :func:`reference_pair` keeps one reference bake of ``passes`` for the layout ``key``."""
    return cache / f"ref_{'_'.join(sorted(passes))}_{size[0]}x{size[1]}_{spp}spp_seed{seed}_{key}.npy"


def coverage_path(cache: Path, size, key: str) -> Path:
    """Where :func:`cycles_coverage` keeps the texels Cycles bakes of the layout ``key``."""
    return cache / f"coverage_{size[0]}x{size[1]}_{key}.npy"


def layout_key(obj) -> str:
    """12 hex digits of the content hash (``core.bake_cache.content_hash``) of ``obj``'s vertex positions and
    ``PDIC_Lightmap`` UVs: which texels a bake of it fills. The unwrap is cached by content, so an unwrap
    changed by new code gets a new key."""
    from pdic.core.bake_cache import content_hash
    from pdic.pdic_addon.uvmaps import LIGHTMAP_UV

    mesh = obj.data
    co = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.vertices.foreach_get("co", co)
    layer = mesh.uv_layers[LIGHTMAP_UV].data
    uv = np.empty(2 * len(layer), np.float32)
    layer.foreach_get("uv", uv)
    return content_hash("layout", co, uv)[:12]


def denoise(image: np.ndarray, mode: str, normal: np.ndarray) -> np.ndarray:
    """OIDN over a Cycles bake: ``RT`` (colour), ``RT+aux`` (albedo 1, clean normals), ``RTLightmap``."""
    import pyoidn

    colour = np.ascontiguousarray(image, np.float32)
    if mode == "RT":
        return pyoidn.denoise(colour, hdr=True)
    if mode == "RT+aux":
        return pyoidn.denoise(colour, np.ones_like(colour), np.ascontiguousarray(normal, np.float32), hdr=True,
                              clean_aux=True)
    if mode == "RTLightmap":
        return pyoidn.denoise(colour, filter_type="RTLightmap")
    raise ValueError(f"unknown denoiser {mode!r}; expected one of {DENOISERS}")


def warm_up_denoisers() -> None:
    """Run each OIDN filter once on a tiny image: OIDN loads its weights on first use, which is not a
    cost of the cheapest rung."""
    for mode in DENOISERS:
        denoise(np.ones((16, 16, 3), np.float32), mode, np.ones((16, 16, 3), np.float32))


def cycles_ladder(obj, size, spec: SceneSpec, refs: dict, mask, normal, keep_spp: int, interior=None) -> tuple:
    """Raw and denoised Cycles bakes on the ladder: (rows, {(kind, method): image at ``keep_spp``})."""
    rows, kept = [], {}
    warm_up_denoisers()
    for spp in spec.ladder:
        for kind, passes in PASS_SETS.items():
            bake = cycles_bake(obj, size, passes, spp, LADDER_SEED)
            variants = [("Cycles", bake["image"], 0.0, 0.0)]
            for mode in DENOISERS:
                out, wall, cpu = clocked(denoise, bake["image"], mode, normal)
                variants.append((f"Cycles + OIDN {mode}", out, wall, cpu))
            for method, image, wall, cpu in variants:
                err = errors(image, refs[kind], mask, interior)
                rows.append(dict(method=method, kind=kind, spp=spp, wall=bake["wall"] + wall,
                                 cpu=bake["cpu"] + cpu, denoise_wall=wall, denoise_cpu=cpu,
                                 **_error_fields(err), mean_ratio=err["mean_ratio"]))
                log("competitors", spec.label, {k: v for k, v in rows[-1].items()})
                if spp == keep_spp:
                    kept[(kind, method)] = image
    return rows, kept


# --------------------------------------------------------------------------- PDIC
def pdic_runs(scene, name: str, refs: dict, mask, save_to: Path | None = None, interior=None) -> tuple:
    """PDIC Final and Preview at defaults: (rows, {(kind, method): image} of Final)."""
    from pdic.core.pipeline import bake
    from pdic.core.settings import preset

    rows, kept = [], {}
    for quality in ("FINAL", "PREVIEW"):
        result, wall, cpu = clocked(bake, scene, preset(quality))
        method = f"PDIC {quality.title()}"
        images = {"all": result.as_cycles(name), "indirect": result.indirect[name]}
        counters = result.stats.get("counters", {})
        for kind, image in images.items():
            err = errors(image, refs[kind], mask & result.centre_inside[name], interior)
            rows.append(dict(method=method, kind=kind, wall=wall, cpu=cpu, **_error_fields(err),
                             mean_ratio=err["mean_ratio"], records=counters.get("records_total"),
                             stage_seconds=result.stats.get("seconds", {})))
            log("competitors", method, {k: v for k, v in rows[-1].items() if k != "stage_seconds"})
            if quality == "FINAL":
                kept[(kind, method)] = image
    if save_to is not None:  # PDIC Final's maps, for looking into its error after the run
        np.savez_compressed(save_to, **{f"{kind}": img for (kind, _), img in kept.items()})
    return rows, kept


# --------------------------------------------------------------------------- equal error
def cycles_cpu_at_error(rows: list, method: str, kind: str, metric: str, error: float):
    """Cycles' CPU seconds at ``error`` on its ladder, log-log interpolated between rungs.

    Returns (seconds, how): how = "interpolated", "extrapolated" (beyond the ladder, from its last
    two rungs' power law) or None when the ladder does not fall (e.g. a denoiser's bias floor).
    """
    pts = sorted((r["cpu"], r[f"error_{metric}"]) for r in rows if r["method"] == method and r["kind"] == kind)
    if len(pts) < 2:
        return None, None
    t, e = np.log([p[0] for p in pts]), np.log([max(p[1], 1e-9) for p in pts])
    target = np.log(max(error, 1e-9))
    for i in range(len(pts) - 1):
        lo, hi = sorted((e[i], e[i + 1]))
        if lo <= target <= hi and e[i] != e[i + 1]:
            f = (target - e[i]) / (e[i + 1] - e[i])
            return float(np.exp(t[i] + f * (t[i + 1] - t[i]))), "interpolated"
    if target > e[0]:  # coarser than the cheapest rung: Cycles needs at most that rung
        return float(np.exp(t[0])), "at most"
    slope = (e[-1] - e[-2]) / (t[-1] - t[-2])
    if slope >= -0.05:
        return None, None
    return float(np.exp(t[-1] + (target - e[-1]) / slope)), "extrapolated"


def equal_error(cycles_rows: list, pdic_rows: list) -> list:
    """For each PDIC row, kind and metric: every Cycles variant's CPU seconds at PDIC's error."""
    out = []
    methods = sorted({r["method"] for r in cycles_rows})
    for p in pdic_rows:
        for metric in (m for m in METRICS if f"error_{m}" in p):
            row = dict(pdic=p["method"], kind=p["kind"], metric=metric, error=p[f"error_{metric}"], pdic_cpu=p["cpu"],
                       pdic_wall=p["wall"], cycles={})
            for method in methods:
                seconds, how = cycles_cpu_at_error(cycles_rows, method, p["kind"], metric, p[f"error_{metric}"])
                row["cycles"][method] = dict(cpu=seconds, how=how,
                                             speedup=None if seconds is None else seconds / p["cpu"])
            out.append(row)
    return out


# --------------------------------------------------------------------------- crops
def crop_window(position: np.ndarray, mask: np.ndarray, world: tuple, side: int = CROP) -> tuple:
    """(row0, col0) of a ``side`` x ``side`` window centred on the covered texel nearest to ``world``."""
    d = np.linalg.norm(position - np.asarray(world, np.float64), axis=2)
    d[~mask] = np.inf
    r, c = np.unravel_index(int(np.argmin(d)), d.shape)
    h, w = mask.shape
    return int(np.clip(r - side // 2, 0, max(h - side, 0))), int(np.clip(c - side // 2, 0, max(w - side, 0)))


def crops(images: dict, window: tuple, side: int = CROP) -> dict:
    """{"kind|method": (side, side, 3) float32} cut from each image at ``window``."""
    r, c = window
    return {f"{kind}|{method}": np.ascontiguousarray(img[r:r + side, c:c + side], np.float32)
            for (kind, method), img in images.items()}


# --------------------------------------------------------------------------- one scene
def run_scene(key: str, spec: SceneSpec, results: Path) -> dict:
    """Every bake of one scene; crops are written to ``results/competitors_crops_<key>.npz``."""
    work = results / "competitors" / key
    obj, scene = load_scene(spec, work)
    set_cycles_threads(2)
    target = scene.targets[0]
    size = (target.width, target.height)
    position, normal, centre = texel_geometry(scene)
    baked = cycles_coverage(obj, size, work)
    mask = centre & baked  # the texels both bake (module docstring)
    pdic_alone, cycles_alone = int((centre & ~baked).sum()), int((baked & ~centre).sum())
    log("competitors", spec.label, f"{size[0]}x{size[1]}, {int(mask.sum()):,} texels both bake "
        f"({pdic_alone:,} PDIC's alone, {cycles_alone:,} Cycles' alone), "
        f"{scene.geometry.count:,} triangles")
    refs = {kind: reference_pair(obj, size, passes, spec.reference_spp, work) for kind, passes in PASS_SETS.items()}
    from pdic.bench.run import interior_texels

    interior = interior_texels(scene)[target.name]
    pdic, pdic_images = pdic_runs(scene, target.name, refs, mask, work / "pdic_final.npz", interior)
    keep = spec.ladder[min(2, len(spec.ladder) - 1)]
    cycles, cycles_images = cycles_ladder(obj, size, spec, refs, mask, normal, keep, interior)
    window = crop_window(position, mask, spec.crop_world)
    cut = crops({**pdic_images, **cycles_images, **{(k, "reference"): 0.5 * (a + b) for k, (a, b) in refs.items()}},
                window)
    r, c = window
    np.savez_compressed(results / f"competitors_crops_{key}.npz", mask=mask[r:r + CROP, c:c + CROP], **cut)
    noise = {k: _seed_noise(a, b, mask) for k, (a, b) in refs.items()}
    return dict(label=spec.label, width=size[0], height=size[1], texels=int(mask.sum()),
                interior_texels=int((mask & interior).sum()), texels_pdic_alone=pdic_alone,
                texels_cycles_alone=cycles_alone,
                triangles=int(scene.geometry.count), ladder=list(spec.ladder), reference_spp=spec.reference_spp,
                reference_noise=noise, crop_spp=keep, crop_window=list(window), crop_world=list(spec.crop_world),
                pdic=pdic, cycles=cycles, equal_error=equal_error(cycles, pdic))


def _seed_noise(a, b, mask) -> float:
    from pdic.bench.run import seed_noise

    return seed_noise(dict(images={"m": a}, coverage={"m": mask}), dict(images={"m": b}, coverage={"m": mask}))


def _previous_scenes(path: Path) -> dict:
    """Scenes of an earlier competitors run, kept when a run names other scenes."""
    import json

    try:
        return json.loads(path.read_text()).get("competitors", {}).get("scenes", {})
    except (OSError, ValueError):
        return {}


def section(quick: bool, names: str = "", results: Path | None = None) -> dict:
    """The ``competitors`` bench section: every named scene (default: the non-optional ones)."""
    from pdic.bench.run import RESULTS

    results = Path(results or RESULTS)
    keys = [k.strip() for k in (names or ",".join(DEFAULT_SCENES)).split(",") if k.strip()]
    try:
        import pyoidn  # noqa: F401  (fail before an hour of bakes, not after)
    except ImportError as e:
        raise SystemExit(f"the competitors section needs pyoidn: pip install -r requirements-bench.txt ({e})")
    unknown = [k for k in keys if k not in SCENES]
    if unknown:
        raise SystemExit(f"--competitors: unknown scene(s) {unknown}; known: {sorted(SCENES)}")
    out = dict(cycles_bounces=CYCLES_BOUNCES, margin=MARGIN, block=BLOCK, denoisers=list(DENOISERS),
               scenes=_previous_scenes(results / "results.json") if not quick else {})
    for key in (["cornell256"] if quick else keys):
        spec = replace(SCENES[key], label=f"{SCENES[key].label} (quick: 64^2)", **QUICK) if quick else SCENES[key]
        out["scenes"][key] = run_scene(key, spec, results)
    return out


if __name__ == "__main__":
    import argparse
    import sys

    ap = argparse.ArgumentParser(prog="bench.competitors", description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default=",".join(DEFAULT_SCENES), help=f"comma-separated: {', '.join(SCENES)}")
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script: the repository's bench.run
    sys.exit(__import__("bench.run", fromlist=["main"]).main(["--only", "competitors", "--competitors", a.scenes]
                                                            + (["--quick"] if a.quick else [])))


# --------------------------------------------------------------------------- report (no bpy: bench/report.py)
def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.2f}"


def _s(x) -> str:
    return "-" if x is None else (f"{x:,.0f}" if x >= 100 else f"{x:.3g}")


def markdown(c: dict) -> str:
    """The competitors section of results.md: per scene the ladder, PDIC and the equal-error table."""
    out = [f"\n## Cycles + OIDN against PDIC at equal error (bench/competitors.py)\n\n"
           f"One object per scene, PDIC's own `PDIC_Lightmap` UVs; Cycles Diffuse (no Color), adaptive off, "
           f"{c['cycles_bounces']} diffuse bounces, no clamping, {c['margin']}-texel margin, denoised by OIDN "
           f"(RT: colour; RT+aux: albedo 1 and the texels' normals; RTLightmap). Errors: relative RMSE over the "
           f"texels both bakers bake (centre on a triangle by PDIC's rasteriser, baked by Cycles without margin: "
           f"a chart's outer row of centres lies on its edge, where the two decide differently, and Cycles fills "
           f"the texels it leaves from the faces beside), per texel and on {c['block']}x{c['block']} block means, "
           f"noise-corrected against a pair of reference bakes (seeds 1, 2); *interior*: the same over the texels "
           f"whose 2x2 samples all lie on the mesh and whose 8 neighbours are covered (at a chart's edge Cycles' "
           f"bake averages points past the triangle, PDIC its samples on it: bench/run.py `interior_texels`). "
           f"CPU s = process time of bake + denoise (all threads; the comparable number on a shared machine), "
           f"wall s beside it. PDIC: core bake at preset defaults.\n"]
    for key, s in c["scenes"].items():
        inner = f" ({s['interior_texels']:,} interior)" if "interior_texels" in s else ""
        texels = "texels"  # runs before session 50 compared over PDIC's texels alone
        if "texels_pdic_alone" in s:
            texels = "texels both bake"
            inner += (f"; {s['texels_pdic_alone']:,} more PDIC bakes alone, {s['texels_cycles_alone']:,} Cycles "
                      f"alone, not compared")
        out.append(f"\n### {s['label']}: {s['width']}x{s['height']}, {s['texels']:,} {texels}{inner}, "
                   f"{s['triangles']:,} triangles; reference {s['reference_spp']} spp x 2 (its own noise per texel: "
                   f"{_pct(s['reference_noise']['all'])} % all, {_pct(s['reference_noise']['indirect'])} % indirect)\n\n")
        rows = []
        by = {(r["method"], r.get("spp"), r["kind"]): r for r in s["cycles"] + s["pdic"]}
        for method, spp in dict.fromkeys((r["method"], r.get("spp")) for r in s["pdic"] + s["cycles"]):
            a, i = by.get((method, spp, "all")), by.get((method, spp, "indirect"))
            rows.append([method, "-" if spp is None else spp, _s(a["cpu"]), _s(a["wall"]), _pct(a["error_texel"]),
                         _pct(a["error_block"]), _pct(a.get("error_texel_interior")),
                         _pct(a.get("error_block_interior")), _s(i["cpu"]), _pct(i["error_texel"]),
                         _pct(i["error_block"]), _pct(i.get("error_texel_interior")),
                         _pct(i.get("error_block_interior")), _ratio(a), _ratio(i)])
        b = f"{c['block']}x{c['block']}"
        out.append(_md_table(["method", "spp", "CPU s", "wall s", "all: texel %", f"all: {b} %", "all interior: texel %",
                              f"all interior: {b} %", "indirect bake CPU s", "indirect: texel %", f"indirect: {b} %",
                              "indirect interior: texel %", f"indirect interior: {b} %",
                              "mean / reference: all", "indirect"],
                             rows))
        out.append("\nCycles' CPU seconds at PDIC's error (log-log interpolated on the ladder; 'at most' = PDIC's "
                   "error is above the cheapest rung's; 'extrapolated' = below the ladder, by its last two rungs; "
                   "'-' = the ladder stops falling before PDIC's error), and in brackets that / PDIC's CPU s (above 1x: PDIC is faster):\n\n")
        methods = list(dict.fromkeys(r["method"] for r in s["cycles"]))
        rows = []
        for e in s["equal_error"]:
            cells = []
            for m in methods:
                v = e["cycles"][m]
                cells.append("-" if v["cpu"] is None else
                             f"{_s(v['cpu'])} ({v['speedup']:.2f}x{', ' + v['how'] if v['how'] != 'interpolated' else ''})")
            rows.append([e["pdic"], e["kind"], e["metric"], _pct(e["error"]), _s(e["pdic_cpu"])] + cells)
        out.append(_md_table(["PDIC", "kind", "metric", "error %", "PDIC CPU s"] + methods, rows))
    return "".join(out)


def _ratio(row: dict) -> str:
    return "-" if row.get("mean_ratio") is None else f"{row['mean_ratio']:.3f}"


def _md_table(header: list, rows: list) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(str(x) for x in r) + " |" for r in rows]) + "\n"


def plots(c: dict, out: Path, plt) -> list:
    """Time-against-error plots and crop sheets, one of each per scene: the PNG names written to ``out``."""
    written = []
    for key, s in c["scenes"].items():
        fig, axes = plt.subplots(2, 2, figsize=(10, 7.5), dpi=90)
        for (kind, metric), ax in zip([(k, m) for k in ("all", "indirect") for m in ("texel", "block")], axes.ravel()):
            for method in dict.fromkeys(r["method"] for r in s["cycles"]):
                rs = [r for r in s["cycles"] if r["method"] == method and r["kind"] == kind]
                ax.loglog([r["cpu"] for r in rs], [100 * r[f"error_{metric}"] for r in rs], "o-", ms=3, label=method)
                if method == "Cycles":
                    for r in rs:
                        ax.annotate(f"{r['spp']}", (r["cpu"], 100 * r[f"error_{metric}"]), fontsize=7)
            for r, style in zip([r for r in s["pdic"] if r["kind"] == kind], ("D", "^")):
                ax.loglog([r["cpu"]], [100 * r[f"error_{metric}"]], style, ms=8, label=r["method"])
            ax.set_title(f"{'direct+indirect' if kind == 'all' else 'indirect only'}, per "
                         f"{'texel' if metric == 'texel' else str(c['block']) + 'x' + str(c['block']) + ' block'}",
                         fontsize=9)
            ax.yaxis.set_major_formatter(plt.matplotlib.ticker.ScalarFormatter())
            ax.yaxis.set_minor_formatter(plt.matplotlib.ticker.NullFormatter())
            ax.set_xlabel("CPU seconds (bake + denoise)")
            ax.set_ylabel("relative RMSE %")
            ax.grid(True, which="both", alpha=0.3)
        axes[0, 0].legend(fontsize=7)
        fig.suptitle(s["label"])
        fig.tight_layout()
        fig.savefig(out / f"competitors_{key}.png")
        plt.close(fig)
        written.append(f"competitors_{key}.png")
        crops_path = out / f"competitors_crops_{key}.npz"
        if crops_path.exists():
            written.append(_crop_sheet(key, s, np.load(crops_path), out, plt))
    return written


def _crop_sheet(key: str, s: dict, cut, out: Path, plt) -> str:
    """Reference, Cycles raw and denoised at the crop's spp, PDIC Final: one row per kind, one scale per row."""
    methods = ["reference", "Cycles"] + [f"Cycles + OIDN {m}" for m in DENOISERS] + ["PDIC Final"]
    fig, axes = plt.subplots(2, len(methods), figsize=(2.1 * len(methods), 4.6), dpi=90)
    for row, kind in enumerate(("all", "indirect")):
        ref = cut[f"{kind}|reference"]
        vmax = max(float(np.percentile(ref, 99)), 1e-30)
        shown = cut["mask"][..., None] if "mask" in cut else 1.0  # the compared texels only
        for col, method in enumerate(methods):
            ax = axes[row, col]
            name = f"{kind}|{method}"
            if name in cut:
                ax.imshow(np.clip(shown * cut[name] / vmax, 0, 1) ** (1 / 2.2), origin="lower",
                          interpolation="nearest")
            label = method.replace("Cycles + OIDN ", "OIDN ")
            if method.startswith("Cycles"):
                label += f" {s['crop_spp']} spp"
            ax.set_title(f"{label}\n{'all' if kind == 'all' else 'indirect'}", fontsize=7)
            ax.axis("off")
    fig.suptitle(f"{s['label']}: {CROP}x{CROP} texels at {tuple(s['crop_world'])} m", fontsize=9)
    fig.tight_layout()
    name = f"competitors_crops_{key}.png"
    fig.savefig(out / name)
    plt.close(fig)
    return name
