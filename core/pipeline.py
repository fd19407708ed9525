"""The bake, as the paper's sequence of passes (STYLE.md principle 3).

    build the BVH -> rasterise texels -> direct light at texels
    -> pass 1: trace photons -> pass 2: irradiance cache (Algorithm 1)
    -> pass 3: refine records (Final quality) -> interpolate at texels, filling holes
    -> light maps: (E_direct + E_indirect) / pi, dilated

Heavy stages are pure functions over chunks of arrays mapped on an
:class:`~core.executor.Executor`; each chunk draws its random numbers from
``default_rng([seed, stage, chunk])`` so results do not depend on the thread
count or scheduling.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from . import texels as texel_stage
from .bake_cache import BakeCache, target_key, transport_key
from .dilate import dilate
from .direct import DirectResult, direct_irradiance
from .executor import Executor, Progress, default_workers
from .interpolation import CacheLookup
from .irradiance_cache import (CacheParameters, IrradianceCache, PhotonDensity, generate_irradiance_cache,
                               neighbour_clamp, place_records)
from .photons import PhotonMap, trace_photons
from .rays import RayCaster
from .refinement import refine_records
from .scene import Scene, SceneError
from .settings import BakeSettings
from .stats import BakeStats
from .validity import inside_geometry

TEXEL_CHUNK = 32_768
"""Texel samples per shading chunk (about 0.05-0.5 s of work: cancel stays responsive)."""
PHOTON_DIRECT_SAMPLES = 2
"""Shadow-ray samples per photon for its direct irradiance (section 3.1); noise averages over cells."""
HOLE_ROUNDS = 3
"""Rounds of hole records (section 3.4) before falling back to the nearest record."""
NEAREST_RECORDS = 8
"""Records the last-resort fallback tries, nearest first, for one that sees the texel sample."""
FINE_ZONE_TEXELS = 4.0
"""Texels whose smallest accepted zone of influence is narrower than this many texels are
interpolated per sample rather than once at their centroid."""

# Stream ids for per-chunk random generators.
_STREAM_DIRECT, _STREAM_PHOTON_DIRECT, _STREAM_VALIDITY = 10, 11, 12


@dataclass
class BakeResult:
    """What a bake returns.

    lightmaps : target name -> (H, W, 4) float32 linear RGBA; RGB = E / pi (Cycles' Diffuse
        Direct+Indirect without colour), alpha = 1 where the texel is covered or dilated.
    centre_inside : target name -> (H, W) bool, texels whose centre lies on a triangle
        (the texels Cycles bakes; comparisons use this mask).
    stats : JSON-ready statistics (see core/manifest.py).
    cache : the irradiance cache (None when indirect light was not baked).
    photons : the photon map (None when indirect light was not baked).
    """

    lightmaps: dict = field(default_factory=dict)
    centre_inside: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    cache: IrradianceCache | None = None
    photons: PhotonMap | None = None
    direct: dict = field(default_factory=dict)
    indirect: dict = field(default_factory=dict)


def bake(scene: Scene, settings: BakeSettings, progress: Progress | None = None,
         executor: Executor | None = None, cache: BakeCache | None = None) -> BakeResult:
    """Bake light maps for every target of ``scene``.

    cache : intermediates from earlier bakes to reuse, and where to store this bake's
        (:class:`~core.bake_cache.BakeCache`, content-keyed); None computes everything.
        An unchanged scene re-baked with the same cache traces no photon and casts no
        ray (counters ``photon_rays``, ``rays_cast`` are 0); changing one object's
        resolution redoes only that object's texels.
    """
    progress = progress or Progress()
    own_executor = executor is None
    executor = executor or Executor(settings.threads or default_workers())
    stats = BakeStats()
    try:
        return _bake(scene, settings, progress, executor, stats, cache)
    finally:
        if own_executor:
            executor.close()


@dataclass
class _TargetWork:
    """One target's texel samples and what has been computed for them."""

    points: texel_stage.TexelPoints
    raster: texel_stage.TargetRaster
    key: str
    E_direct: np.ndarray | None = None
    E_indirect: np.ndarray | None = None
    holes: IrradianceCache | None = None
    texel_size: float = 0.0
    """World size of one of the target's texels (sqrt of its area per covered texel)."""


def _bake(scene: Scene, settings: BakeSettings, progress: Progress, executor: Executor, stats: BakeStats,
          store: BakeCache | None):
    if not scene.targets:
        raise SceneError("nothing to bake: the scene has no bake targets")
    if not scene.has_light():
        raise SceneError("nothing emits light: add a light, an emissive material or a world colour")
    transport = transport_key(scene) if store is not None else ""
    stats.set(triangles=scene.geometry.count, targets=len(scene.targets),
              emissive_triangles=len(scene.emissive_triangles), lights=len(scene.lights))
    caster_box: list = []

    def caster() -> RayCaster:  # the BVH is built only if some stage casts rays
        if not caster_box:
            progress.begin("Building BVH")
            with stats.stage("bvh"):
                caster_box.append(RayCaster(scene.geometry.positions, scene.extent, executor, scene.geometry.transmission))
        return caster_box[0]

    # -- texel samples, per target (only the scene's targets: objects not baked are never rasterised)
    progress.begin("Rasterising texels")
    work: list[_TargetWork] = []
    rasterised = 0
    with stats.stage("rasterise"):
        for target in scene.targets:
            key = target_key(scene, target, settings.texel_samples)  # also seeds the target's streams
            cached = _get(store, "raster", key)
            if cached is None:
                points, rasters = texel_stage.lift_texels(replace(scene, targets=(target,)), settings.texel_samples)
                cached = (points, rasters[0])
                _put(store, "raster", key, cached)
                rasterised += 1
            covered = max(int(cached[1].coverage.sum()), 1)
            texel_size = float(np.sqrt(scene.geometry.areas()[target.triangles].sum() / covered))
            work.append(_TargetWork(cached[0], cached[1], key, texel_size=texel_size))
    rasters = [w.raster for w in work]
    stats.set(texel_samples=sum(len(w.points) for w in work),
              texels_covered=int(sum(r.coverage.sum() for r in rasters)), targets_rasterised=rasterised)

    # -- direct light at the texels of each target not already shaded
    direct_key = lambda w: store.key("direct", transport, w.key, settings.direct_samples, settings.seed)  # noqa: E731
    for w in work:
        w.E_direct = np.zeros((len(w.points), 3))
    if settings.direct:
        todo = []
        for w in work:
            cached = _get(store, "direct", direct_key(w) if store is not None else "")
            if cached is not None:
                w.E_direct = cached
            else:
                todo.append(w)
        stats.set(targets_shaded_direct=len(todo))
        if todo:
            progress.begin("Direct light")
            with stats.stage("direct"):
                for w in todo:
                    p = w.points
                    w.E_direct, counters = shade_direct(scene, caster(), p.p, p.n_shading, p.n_geometric,
                                                        settings.direct_samples, settings.seed,
                                                        (_STREAM_DIRECT, _stream_of(w.key)),
                                                        executor, progress)
                    stats.add(**counters)
                    if store is not None:
                        _put(store, "direct", direct_key(w), w.E_direct)

    # -- indirect light: passes 1-3 only if some target still needs it
    base_cache = photon_map = density = None
    for w in work:
        w.E_indirect = np.zeros((len(w.points), 3))
    if settings.indirect and settings.photons > 0:
        params = cache_parameters(scene, rasters, settings)
        photon_bounces = settings.max_bounces - 1 if settings.refine else settings.max_bounces
        photon_key = store.key("photons", transport, settings.photons, photon_bounces, settings.seed) \
            if store is not None else ""
        cache_key = store.key("cache", photon_key, params, settings.refine, settings.hemisphere_theta,
                              settings.hemisphere_phi, settings.reuse_photon_paths) if store is not None else ""
        indirect_key = lambda w: store.key("indirect", cache_key, w.key, settings.gradients)  # noqa: E731
        todo = []
        for w in work:
            cached = _get(store, "indirect", indirect_key(w) if store is not None else "")
            if cached is not None:
                w.E_indirect, w.holes = cached
            else:
                todo.append(w)
        stats.set(targets_shaded_indirect=len(todo))
        cached = _get(store, "cache", cache_key) if todo else None
        if cached is not None:
            base_cache, photon_map = cached
        elif todo:
            photon_map = _get(store, "photons", photon_key)
            if photon_map is None:
                photon_map = trace_pass(scene, caster(), settings, photon_bounces, executor, progress, stats)
                _put(store, "photons", photon_key, photon_map)
            # Passes 2-3 write the section 3.1 fields; give them their own arrays so a stored map
            # (and caches built on it with other parameters) keeps its own.
            photon_map = replace(photon_map, w_sum=np.zeros_like(photon_map.w_sum),
                                 E_indirect_sum=np.zeros_like(photon_map.E_indirect_sum),
                                 E_direct=np.zeros_like(photon_map.E_direct))
            base_cache, density = build_cache(scene, caster, photon_map, params, settings, executor, progress,
                                              stats, with_density=True)
            _put(store, "cache", cache_key, (base_cache, photon_map))
        if todo:
            if density is None and len(photon_map):  # the cache came from the store
                density = PhotonDensity(photon_map)
            if density is not None:  # hole records' gathering reads indirect light from this cache
                density.records = base_cache
                density.records_lookup = None
            for w in todo:
                w.E_indirect, w.holes = indirect_at_texels(scene, caster(), density, base_cache, w, params,
                                                           settings, executor, progress, stats)
                if store is not None:
                    _put(store, "indirect", indirect_key(w), (w.E_indirect, w.holes))
        if base_cache is None:  # every target came from the store
            cached = _get(store, "cache", cache_key)
            base_cache, photon_map = cached if cached is not None else (IrradianceCache(), None)
        stats.set(hole_records=int(sum(len(w.holes) for w in work if w.holes is not None)))
        full = base_cache
        for w in work:
            if w.holes is not None and len(w.holes):
                full = full.extend(w.holes)
        base_cache = full
        stats.set(records_total=len(base_cache))

    progress.begin("Writing light maps")
    result = BakeResult(cache=base_cache, photons=photon_map)
    with stats.stage("dilate"):
        for target, w in zip(scene.targets, work):
            direct_img = texel_stage.splat(w.E_direct, w.points, w.raster) / np.pi
            indirect_img = texel_stage.splat(w.E_indirect, w.points, w.raster) / np.pi
            rgb, coverage = dilate((direct_img + indirect_img).astype(np.float32), w.raster.coverage,
                                   settings.padding + 2)
            rgba = np.concatenate([rgb, coverage[..., None].astype(np.float32)], axis=2)
            result.lightmaps[target.name] = _finite(rgba, target.name)
            result.centre_inside[target.name] = w.raster.centre_inside
            result.direct[target.name] = direct_img.astype(np.float32)
            result.indirect[target.name] = indirect_img.astype(np.float32)
    stats.set(rays_cast=caster_box[0].rays_cast if caster_box else 0)
    stats.set(photon_rays=stats.counters.get("photon_rays", 0))
    if store is not None:
        stats.set(**store.counters())
    result.stats = stats.as_dict()
    return result


def _get(store: BakeCache | None, kind: str, key: str):
    return None if store is None else store.get(kind, key)


def _put(store: BakeCache | None, kind: str, key: str, value) -> None:
    if store is not None:
        store.put(kind, key, value)


def _stream_of(key: str) -> int:
    """A per-target random stream id from its content key: the same texels draw the same numbers
    whatever else is baked with them, so a target's light map can be reused on its own."""
    return int(key[:8], 16)


def trace_pass(scene: Scene, caster: RayCaster, settings: BakeSettings, photon_bounces: int, executor: Executor,
               progress: Progress, stats: BakeStats) -> PhotonMap:
    """Pass 1, with its counters."""
    progress.begin("Pass 1: tracing photons")
    with stats.stage("photons"):
        photon_map, trace = trace_photons(scene, caster, settings.photons, photon_bounces, settings.seed,
                                          executor, progress)
    stats.set(photons_emitted=trace.emitted, photons_stored=trace.stored, photon_rays=trace.rays,
              photons_escaped=trace.escaped, photon_emitters=len(trace.emitted_per_light),
              max_bounces=settings.max_bounces, photon_bounces=photon_bounces, photon_bytes=photon_map.nbytes,
              bytes_per_photon=PhotonMap.BYTES_PER_PHOTON)
    return photon_map


def build_cache(scene: Scene, caster, photon_map: PhotonMap, params: CacheParameters, settings: BakeSettings,
                executor: Executor, progress: Progress, stats: BakeStats, with_density: bool = False):
    """Pass 2 (Algorithm 1) and, for Final quality, pass 3 (refinement). ``caster`` is a callable.

    Returns the cache, or (cache, its PhotonDensity or None) ``with_density``: the photons'
    kd-tree costs seconds on big maps, and hole records need it again.
    """
    if len(photon_map) == 0:
        return (IrradianceCache(), None) if with_density else IrradianceCache()
    progress.begin("Pass 2: irradiance cache")
    with stats.stage("cache"):
        density = PhotonDensity(photon_map)
        cache, zones, build = generate_irradiance_cache(density, params, settings.seed, progress, caster=caster())
        cache.R = neighbour_clamp(cache.p, cache.R)
    stats.set(records=build.records, kd_queries=build.kd_queries, R_min=params.R_min, R_max=params.R_max,
              wall_rays=build.wall_rays)
    if settings.refine:
        progress.begin("Pass 3: refining records")
        if settings.reuse_photon_paths:  # only virtual rays read the photons' direct irradiance
            with stats.stage("photon_direct"):
                photon_map.E_direct[:] = shade_direct(
                    scene, caster(), photon_map.p.astype(np.float64), photon_map.n.astype(np.float64),
                    photon_map.n.astype(np.float64), PHOTON_DIRECT_SAMPLES, settings.seed, _STREAM_PHOTON_DIRECT,
                    executor, progress)[0]
        with stats.stage("refine"):
            cache, refine_counters = refine_records(scene, caster(), density, cache, zones, settings, params,
                                                    executor, progress)
        stats.add(**refine_counters)
    return (cache, density) if with_density else cache


def indirect_at_texels(scene: Scene, caster: RayCaster, density: PhotonDensity | None, cache: IrradianceCache,
                       work: _TargetWork, params: CacheParameters, settings: BakeSettings, executor: Executor,
                       progress: Progress, stats: BakeStats) -> tuple[np.ndarray, IrradianceCache]:
    """Texel validity, then Equation 3 with hole records for one target: (E (n, 3), its hole records)."""
    points = work.points
    E = np.zeros((len(points), 3))
    if density is None or len(points) == 0:
        return E, IrradianceCache()
    progress.begin("Texel validity")
    with stats.stage("validity"):
        inside, rays = texel_validity(caster, points, [settings.seed, _STREAM_VALIDITY, _stream_of(work.key)],
                                      executor, progress)
    stats.add(texel_samples_inside_geometry=int(inside.sum()), validity_rays=rays)
    valid = np.flatnonzero(~inside)
    progress.begin("Interpolating the cache at texels")
    with stats.stage("interpolate"):
        valid_points = points.take(valid)
        merged, sample_to_point = valid_points.per_texel()  # inside samples are not averaged in
        E_merged, full, hole_records, unfilled = interpolate_filling_holes(
            scene, caster, density, cache, merged, params, settings, executor, progress)
        E[valid] = E_merged[sample_to_point]
        # Where a zone of influence spans few texels, Equation 3 changes inside a texel (zone
        # edges are steps): there every sample gets its own lookup, as a 2x2 box filter would.
        _, _, smallest = _lookup(full, params.a, settings.gradients, merged.p, merged.n_shading, executor,
                                 progress, with_zone=True, caster=caster)
        fine = np.flatnonzero((smallest < FINE_ZONE_TEXELS * work.texel_size)[sample_to_point])
        if len(fine):
            E_fine, w_fine = _lookup(full, params.a, settings.gradients, valid_points.p[fine],
                                     valid_points.n_shading[fine], executor, progress, caster=caster)
            covered = w_fine > 0
            E[valid[fine[covered]]] = E_fine[covered]
    stats.add(texel_points_interpolated=len(merged) + len(fine), texel_points_unfilled=unfilled)
    return E, full.take(slice(len(cache), None))


def texel_validity(caster: RayCaster, points, seed: list, executor: Executor,
                   progress: Progress) -> tuple[np.ndarray, int]:
    """Which texel samples lie inside closed geometry, chunked over the executor: ((n,) bool, rays cast)."""
    n = len(points)
    chunks = [slice(s, min(s + TEXEL_CHUNK, n)) for s in range(0, n, TEXEL_CHUNK)]
    serial = caster.serial()
    done = [0]

    def run(job):
        index, s = job
        out = inside_geometry(serial, serial.face_normals, points.p[s], points.n_geometric[s],
                              np.random.default_rng([*seed, index]))
        done[0] += 1
        progress.update(done[0] / len(chunks))
        return out

    parts = executor.map(run, list(enumerate(chunks)))
    rays = sum(r for _, r in parts)
    caster.rays_cast += rays
    inside = np.concatenate([i for i, _ in parts]) if parts else np.zeros(0, bool)
    return inside, rays


def shade_direct(scene: Scene, caster: RayCaster, p: np.ndarray, n_shading: np.ndarray, n_geometric: np.ndarray,
                 samples: int, seed: int, stream: int, executor: Executor, progress: Progress
                 ) -> tuple[np.ndarray, dict]:
    """Direct irradiance (n, 3) at surface points, chunked over the executor, plus summed work counters."""
    n = len(p)
    chunks = [slice(s, min(s + TEXEL_CHUNK, n)) for s in range(0, n, TEXEL_CHUNK)]
    serial = caster.serial()
    done = [0]

    def run(job):
        index, s = job
        rng = np.random.default_rng([seed, *np.atleast_1d(stream).tolist(), index])
        out = direct_irradiance(scene, serial, p[s], n_shading[s], n_geometric[s], samples, rng)
        done[0] += 1
        progress.update(done[0] / len(chunks))
        return out

    merged = DirectResult.concatenate(executor.map(run, list(enumerate(chunks))))
    counters = {f"shadow_rays_{k}": v for k, v in merged.shadow_rays.items()}
    counters["shadow_rays"] = sum(merged.shadow_rays.values())
    counters["shadow_rays_skipped_points"] = sum(merged.skipped.values())
    for light, skipped in merged.skipped.items():  # points that cast no ray toward this emitter
        counters[f"shadow_rays_skipped_points:{light}"] = skipped
    caster.rays_cast += counters["shadow_rays"]
    return merged.E, counters


def cache_parameters(scene: Scene, rasters, settings: BakeSettings) -> CacheParameters:
    """R_min from the largest texel's world size, R_max from the scene diagonal."""
    areas = scene.geometry.areas()
    texel_size = 0.0
    for target, raster in zip(scene.targets, rasters):
        covered = max(int(raster.coverage.sum()), 1)
        texel_size = max(texel_size, float(np.sqrt(areas[target.triangles].sum() / covered)))
    R_max = settings.r_max_fraction * scene.extent
    R_min = min(settings.r_min_texels * texel_size, R_max)
    # Preview's light maps are pass 2's E_k, so its kernel is normalised over the surface actually in
    # the disc (Cornell indirect 12.6 -> 7.8 %). Final keeps the plain kernel for now: its virtual
    # rays carry a +4 % bias that the plain kernel's -4 % at edges happens to cancel (Final with the
    # coverage kernel: 7.8 % instead of 6.4 %), so correcting one alone makes Final worse.
    return CacheParameters(a=settings.a, r_nearest=settings.r_nearest, R_min=max(R_min, 1e-9 * scene.extent),
                           R_max=R_max, kernel_coverage=not settings.refine)


def interpolate_filling_holes(scene, caster, density: PhotonDensity, cache: IrradianceCache, points,
                              params: CacheParameters, settings: BakeSettings, executor: Executor,
                              progress: Progress):
    """Equation 3 at every texel sample; samples no record covers get new records (section 3.4)."""
    E, w = _lookup(cache, params.a, settings.gradients, points.p, points.n_shading, executor, progress, caster=caster)
    hole_records = 0
    for round_ in range(HOLE_ROUNDS):
        holes = np.flatnonzero(w <= 0)
        if len(holes) == 0:
            break
        progress.check()
        cand_p, cand_n = points.p[holes], points.n_shading[holes]
        new, zones, _ = place_records(density, cand_p, cand_n, np.zeros(len(holes)), np.zeros((len(holes), 3)),
                                      params, np.random.default_rng([settings.seed, 3, round_]),
                                      candidate_is_photon=False, existing=cache, caster=caster)
        if settings.refine and len(new):
            new, _ = refine_records(scene, caster, density, new, zones, settings, params, executor, progress,
                                    stream=20 + round_)
        hole_records += len(new)
        cache = cache.extend(new)
        E_h, w_h = _lookup(cache, params.a, settings.gradients, cand_p, cand_n, executor, progress, caster=caster)
        E[holes], w[holes] = E_h, w_h
    unfilled = np.flatnonzero(w <= 0)
    if len(unfilled) and len(cache):
        # Last resort, counted in the stats: the nearest record that sees the point (else 0).
        k = min(NEAREST_RECORDS, len(cache))
        _, nearest = cKDTree(cache.p).query(points.p[unfilled], k=k)
        nearest = nearest.reshape(len(unfilled), k)
        p, n = np.repeat(points.p[unfilled], k, axis=0), np.repeat(points.n_shading[unfilled], k, axis=0)
        seen = ~caster.hidden_off_plane(p, n, cache.p[nearest.ravel()], cache.n[nearest.ravel()]).reshape(-1, k)
        first = np.argmax(seen, axis=1)
        E[unfilled] = np.where(seen.any(axis=1)[:, None], cache.E[nearest[np.arange(len(unfilled)), first]], 0.0)
    return E, cache, hole_records, len(unfilled)


def _lookup(cache, a, gradients, p, n, executor: Executor, progress: Progress, with_zone: bool = False,
            caster: RayCaster | None = None):
    """Equation 3 at points, chunked: (E, w_sum), or (E, w_sum, smallest zone) ``with_zone``."""
    lookup = CacheLookup(cache, a, gradients, caster=None if caster is None else caster.serial())
    chunks = [slice(s, min(s + TEXEL_CHUNK, len(p))) for s in range(0, len(p), TEXEL_CHUNK)]
    done = [0]

    def run(s):
        out = (lookup.irradiance_and_zone if with_zone else lookup.irradiance)(p[s], n[s])
        done[0] += 1
        progress.update(done[0] / len(chunks))  # also where a cancel is noticed
        return out

    parts = executor.map(run, chunks)
    if caster is not None:
        caster.rays_cast += lookup.caster.rays_cast  # record-visibility rays
    if not parts:
        parts = [(np.zeros((0, 3)), np.zeros(0), np.zeros(0))[:3 if with_zone else 2]]
    return tuple(np.concatenate([part[i] for part in parts]) for i in range(len(parts[0])))


def _finite(image: np.ndarray, name: str) -> np.ndarray:
    """Light maps never carry NaN or inf silently: fail loudly naming the target."""
    if not np.isfinite(image).all():
        bad = int((~np.isfinite(image)).sum())
        raise FloatingPointError(f"{name}: {bad} non-finite light-map values (please report this scene)")
    return image.astype(np.float32)
