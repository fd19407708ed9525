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

from dataclasses import dataclass, field

import numpy as np

from . import texels as texel_stage
from .dilate import dilate
from .direct import DirectResult, direct_irradiance
from .executor import Executor, Progress, default_workers
from .interpolation import CacheLookup
from .irradiance_cache import (CacheParameters, IrradianceCache, PhotonDensity, generate_irradiance_cache,
                               neighbour_clamp, place_records)
from .photons import PhotonMap, trace_photons
from .rays import RayCaster
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
         executor: Executor | None = None) -> BakeResult:
    """Bake light maps for every target of ``scene``."""
    progress = progress or Progress()
    own_executor = executor is None
    executor = executor or Executor(settings.threads or default_workers())
    stats = BakeStats()
    try:
        return _bake(scene, settings, progress, executor, stats)
    finally:
        if own_executor:
            executor.close()


def _bake(scene: Scene, settings: BakeSettings, progress: Progress, executor: Executor, stats: BakeStats):
    if not scene.targets:
        raise SceneError("nothing to bake: the scene has no bake targets")
    if not scene.has_light():
        raise SceneError("nothing emits light: add a light, an emissive material or a world colour")

    progress.begin("Building BVH")
    with stats.stage("bvh"):
        caster = RayCaster(scene.geometry.positions, scene.extent, executor)
    stats.set(triangles=scene.geometry.count, targets=len(scene.targets))

    progress.begin("Rasterising texels")
    with stats.stage("rasterise"):
        points, rasters = texel_stage.lift_texels(scene, settings.texel_samples)
    stats.set(texel_samples=len(points), texels_covered=int(sum(r.coverage.sum() for r in rasters)))

    E_direct = np.zeros((len(points), 3))
    if settings.direct:
        progress.begin("Direct light")
        with stats.stage("direct"):
            E_direct, counters = shade_direct(scene, caster, points.p, points.n_shading, points.n_geometric,
                                              settings.direct_samples, settings.seed, _STREAM_DIRECT,
                                              executor, progress)
        stats.add(**counters)

    E_indirect = np.zeros((len(points), 3))
    cache = photon_map = None
    if settings.indirect and settings.photons > 0:
        progress.begin("Texel validity")
        with stats.stage("validity"):
            inside, rays = inside_geometry(caster, scene.geometry.face_normals(), points.p, points.n_geometric,
                                           np.random.default_rng([settings.seed, _STREAM_VALIDITY]))
        stats.set(texel_samples_inside_geometry=int(inside.sum()), validity_rays=rays)
        valid = np.flatnonzero(~inside)
        E_valid, cache, photon_map = indirect_light(scene, caster, points.take(valid), rasters, settings,
                                                    executor, progress, stats)
        E_indirect[valid] = E_valid

    progress.begin("Writing light maps")
    result = BakeResult(cache=cache, photons=photon_map)
    with stats.stage("dilate"):
        for i, (target, raster) in enumerate(zip(scene.targets, rasters)):
            direct_img = texel_stage.splat(E_direct, points, raster) / np.pi
            indirect_img = texel_stage.splat(E_indirect, points, raster) / np.pi
            rgb, coverage = dilate((direct_img + indirect_img).astype(np.float32), raster.coverage,
                                   settings.padding + 2)
            rgba = np.concatenate([rgb, coverage[..., None].astype(np.float32)], axis=2)
            result.lightmaps[target.name] = _finite(rgba, target.name)
            result.centre_inside[target.name] = raster.centre_inside
            result.direct[target.name] = direct_img.astype(np.float32)
            result.indirect[target.name] = indirect_img.astype(np.float32)
    stats.set(rays_cast=caster.rays_cast)
    result.stats = stats.as_dict()
    return result


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
        rng = np.random.default_rng([seed, stream, index])
        out = direct_irradiance(scene, serial, p[s], n_shading[s], n_geometric[s], samples, rng)
        done[0] += 1
        progress.update(done[0] / len(chunks))
        return out

    merged = DirectResult.concatenate(executor.map(run, list(enumerate(chunks))))
    counters = {f"shadow_rays_{k}": v for k, v in merged.shadow_rays.items()}
    counters["shadow_rays"] = sum(merged.shadow_rays.values())
    counters["shadow_rays_skipped_points"] = sum(merged.skipped.values())
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
    return CacheParameters(a=settings.a, r_nearest=settings.r_nearest, R_min=max(R_min, 1e-9 * scene.extent),
                           R_max=R_max)


def indirect_light(scene: Scene, caster: RayCaster, points, rasters, settings: BakeSettings,
                   executor: Executor, progress: Progress, stats: BakeStats):
    """Passes 1-3 and the cache lookup at texels; returns (E_indirect (n, 3), cache, photon map)."""
    # Final gathering adds the last bounce itself (the hits' irradiance already holds the photons'
    # bounces), so refined bakes trace one bounce fewer and both qualities count max_bounces alike.
    photon_bounces = settings.max_bounces - 1 if settings.refine else settings.max_bounces
    progress.begin("Pass 1: tracing photons")
    with stats.stage("photons"):
        photon_map, trace = trace_photons(scene, caster, settings.photons, photon_bounces, settings.seed,
                                          executor, progress)
    stats.set(photons_emitted=trace.emitted, photons_stored=trace.stored, photon_rays=trace.rays,
              photons_escaped=trace.escaped, max_bounces=settings.max_bounces, photon_bounces=photon_bounces,
              photon_bytes=photon_map.nbytes, bytes_per_photon=PhotonMap.BYTES_PER_PHOTON)
    if len(photon_map) == 0:
        return np.zeros((len(points), 3)), IrradianceCache(), photon_map

    params = cache_parameters(scene, rasters, settings)
    progress.begin("Pass 2: irradiance cache")
    with stats.stage("cache"):
        density = PhotonDensity(photon_map)
        cache, zones, build = generate_irradiance_cache(density, params, settings.seed, progress)
        cache.R = neighbour_clamp(cache.p, cache.R)
    stats.set(records=build.records, kd_queries=build.kd_queries, R_min=params.R_min, R_max=params.R_max)

    if settings.refine:
        from .refinement import refine_records  # pass 3

        progress.begin("Pass 3: refining records")
        with stats.stage("photon_direct"):
            photon_map.E_direct[:] = shade_direct(
                scene, caster, photon_map.p.astype(np.float64), photon_map.n.astype(np.float64),
                photon_map.n.astype(np.float64), PHOTON_DIRECT_SAMPLES, settings.seed, _STREAM_PHOTON_DIRECT,
                executor, progress)[0]
        with stats.stage("refine"):  # noqa: SIM117 (stages are timed separately)
            cache, refine_counters = refine_records(scene, caster, density, cache, zones, settings, params,
                                                    executor, progress)
        stats.add(**refine_counters)

    progress.begin("Interpolating the cache at texels")
    with stats.stage("interpolate"):
        E, cache, hole_records, unfilled = interpolate_filling_holes(scene, caster, density, cache, points,
                                                                     params, settings, executor, progress)
    stats.set(hole_records=hole_records, texel_samples_unfilled=unfilled, records_total=len(cache))
    return E, cache, photon_map


def interpolate_filling_holes(scene, caster, density: PhotonDensity, cache: IrradianceCache, points,
                              params: CacheParameters, settings: BakeSettings, executor: Executor,
                              progress: Progress):
    """Equation 3 at every texel sample; samples no record covers get new records (section 3.4)."""
    E, w = _lookup(cache, params.a, settings.gradients, points.p, points.n_shading, executor, progress)
    hole_records = 0
    for round_ in range(HOLE_ROUNDS):
        holes = np.flatnonzero(w <= 0)
        if len(holes) == 0:
            break
        progress.check()
        cand_p, cand_n = points.p[holes], points.n_shading[holes]
        new, zones, _ = place_records(density, cand_p, cand_n, np.zeros(len(holes)), np.zeros((len(holes), 3)),
                                      params, np.random.default_rng([settings.seed, 3, round_]),
                                      candidate_is_photon=False, existing=cache)
        if settings.refine and len(new):
            from .refinement import refine_records

            new, _ = refine_records(scene, caster, density, new, zones, settings, params, executor, progress,
                                    stream=20 + round_)
        hole_records += len(new)
        cache = cache.extend(new)
        E_h, w_h = _lookup(cache, params.a, settings.gradients, cand_p, cand_n, executor, progress)
        E[holes], w[holes] = E_h, w_h
    unfilled = np.flatnonzero(w <= 0)
    if len(unfilled) and len(cache):
        # Last resort, counted in the stats: the nearest record's irradiance.
        from scipy.spatial import cKDTree

        _, nearest = cKDTree(cache.p).query(points.p[unfilled])
        E[unfilled] = cache.E[nearest]
    return E, cache, hole_records, len(unfilled)


def _lookup(cache, a, gradients, p, n, executor: Executor, progress: Progress):
    lookup = CacheLookup(cache, a, gradients)
    chunks = [slice(s, min(s + TEXEL_CHUNK, len(p))) for s in range(0, len(p), TEXEL_CHUNK)]
    done = [0]

    def run(s):
        out = lookup.irradiance(p[s], n[s])
        done[0] += 1
        progress.update(done[0] / len(chunks))  # also where a cancel is noticed
        return out

    parts = executor.map(run, chunks)
    if not parts:
        return np.zeros((0, 3)), np.zeros(0)
    return np.concatenate([e for e, _ in parts]), np.concatenate([w for _, w in parts])


def _finite(image: np.ndarray, name: str) -> np.ndarray:
    """Light maps never carry NaN or inf silently: fail loudly naming the target."""
    if not np.isfinite(image).all():
        bad = int((~np.isfinite(image)).sum())
        raise FloatingPointError(f"{name}: {bad} non-finite light-map values (please report this scene)")
    return image.astype(np.float32)
