"""Pass 3: refine every record by final gathering that reuses photon paths (section 3.3, Figure 4).

For record k, the hemisphere above p_k is split into equal-weight cells (:mod:`core.hemisphere`).
A batch of records is refined in four named steps, cut along Figure 4:

1. :func:`probe` - a few real rays per record (deviation: probe-rays);
2. :func:`~core.virtual_rays.fill_virtual` - virtual rays from the zones' photon paths (4a-b);
3. :func:`~core.real_rays.trace_real` - one real ray per cell no ray reached (4c), then
   :func:`~core.real_rays.shade_real` - radiance at all the batch's real hits at once;
4. :meth:`~core.gather_cells.CellSums.irradiance_and_gradients` - the refined E_k, its rotational
   and translational gradients and a new R_k (harmonic mean of the distances, clamped again).

With ``reuse_photon_paths=False`` every cell casts a ray: the standard stratified final
gathering the paper compares against (Table 2). Batches are pure functions of their slice of
the cache, mapped on the executor.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial

import numpy as np

from .constants import (BACKFACE_FRACTION, CELL_DISTANCE_FLOOR, GATHER_DARK, GATHER_ERROR, GATHER_ROUNDS,
                        INSIDE_RECORD_RADIUS, PHOTON_DIRECT_SAMPLES, PROBE_RAYS, STREAM_HIT_GRID, STREAM_PHOTON_DIRECT,
                        STREAM_REFINE, VALIDITY_RAYS, VIRTUAL_RADIUS)
from .density import PhotonDensity
from .direct import shade_direct
from .executor import Executor, Progress, slices
from .gather_cells import CellSums, limit_gradients
from .hemisphere import Hemisphere, local_frames
from .hit_radiance import HitGrid, build_hit_grid
from .interpolation import CacheLookup
from .irradiance_cache import CacheParameters, IrradianceCache, Zones, neighbour_clamp
from .photons import PhotonLighting
from .real_rays import RealHits, indirect_on_both_sides, seeing, shade_real, through_glass, trace_real
from .record_walls import open_walls, wall_distances
from .settings import BakeSettings, Deviations
from .validity import closed_backs, open_backs, overrule_by_photons
from .virtual_rays import fill_virtual

RECORD_BATCH = 256
"""Records refined per chunk: ~75k cells, a few tenths of a second of work."""
COUNTERS = ("refine_rays_cast", "refine_probe_rays", "refine_visibility_rays", "refine_path_visibility_rays",
            "refine_shadow_rays", "refine_gap_hits",
            "refine_virtual_rays", "refine_cells_virtual", "refine_cells", "refine_records_inside",
            "refine_extra_gathers")


@dataclass(frozen=True)
class GatherSources:
    """What pass 3 reads where its rays end (built once per bake, read-only).

    density : the photons' kd-tree (zones, nearest-photon fallback).
    lighting : the photons' section 3.1 sums from pass 2 (+ E_direct when paths are reused).
    lookup : Equation 3 over the records gathered so far, without gradients: E_indirect at hits.
    radiance_out : (N, 3) float64 radiance leaving each photon (virtual rays), None without reuse.
    hit_grid : irradiance over every triangle that hits read instead (deviation: hit-grid), or None.
    gap_reach : a R_min, scene units: a gap hit's walk bounces on while it stays this near (deviation:
        gap-gathering, :func:`core.real_rays.gap_irradiance`).
    sky : the world's radiance (3,) that escaping gathering rays bring to the records' sky channels
        (deviation: sky-gathering, :func:`core.sky_gathering.gathered_sky`), or None.
    """

    density: PhotonDensity
    lighting: PhotonLighting
    lookup: CacheLookup
    radiance_out: np.ndarray | None
    deviations: Deviations
    hit_grid: HitGrid | None = None
    gap_reach: float = 0.0
    sky: np.ndarray | None = None

    @property
    def nearest_photon_fallback(self) -> bool:
        return self.deviations.nearest_photon_fallback


def gather_sources(density: PhotonDensity, lighting: PhotonLighting, records: IrradianceCache,
                   params: CacheParameters, settings: BakeSettings, scene=None, caster=None,
                   executor: Executor | None = None, progress: Progress | None = None, use: int = 0,
                   direct_from: HitGrid | None = None, sky: np.ndarray | None = None) -> tuple[GatherSources, dict]:
    """Pass 3's read-only inputs: records interpolated at hits, radiance leaving each photon, and
    (deviation: hit-grid, given the scene) the grid of irradiance hits read; plus its counters.

    use : 0 for pass 3, 1 for the hole records (the random stream of the grid's shadow rays).
    direct_from : pass 3's grid, whose direct light the hole records' grid reuses.
    sky : :attr:`GatherSources.sky`.
    """
    radiance_out = lighting.radiance_out(density.photons.albedo) if settings.reuse_photon_paths else None
    lookup = CacheLookup(records, params.a, use_gradients=False, layers=True)
    sources = GatherSources(density, lighting, lookup, radiance_out, settings.deviations,
                            gap_reach=params.a * params.R_min, sky=sky)
    if not settings.deviations.hit_grid or scene is None:
        return sources, {}
    if progress is not None:
        progress.begin(("Pass 3" if use == 0 else "Hole records") + ": irradiance over the hit grid")

    def indirect_at(q, n, known):
        view = caster.serial()  # this chunk's rays: the records' visibility test and the fallback
        # deviation: record-visibility: a cell on the back of a wall must not read the records a
        # centimetre in front of it (the slot between a flipped wall's faces read the tracery's backs).
        front, back, _, picks = indirect_on_both_sides(view, seeing(sources, view), q, n, known)
        return front, back, view.rays_cast, picks

    hits = len(records) * settings.hemisphere_theta * settings.hemisphere_phi
    grid, counters = build_hit_grid(scene, caster, indirect_at, params.R_min, hits, settings.seed,
                                    [STREAM_HIT_GRID, use], executor, progress, direct_from,
                                    settings.deviations.open_cells, settings.deviations.light_budget)
    caster.rays_cast += counters["hit_grid_lookup_rays"] + counters["hit_grid_open_rays"]
    return replace(sources, hit_grid=grid), counters


def light_photons(scene, caster, photons, lighting: PhotonLighting, settings: BakeSettings, executor: Executor,
                  progress: Progress, stats) -> PhotonLighting:
    """The photons' direct irradiance (section 3.1), which only virtual rays read: a new value."""
    if not settings.reuse_photon_paths:
        return lighting
    with stats.stage("photon_direct"):
        p = photons.p.astype(np.float64)
        n = photons.n.astype(np.float64)
        E_direct = shade_direct(scene, caster, p, n, n, PHOTON_DIRECT_SAMPLES, settings.seed,
                                STREAM_PHOTON_DIRECT, executor, progress, budget=settings.deviations.light_budget)[0]
    return PhotonLighting(lighting.w_sum, lighting.E_indirect_sum, E_direct.astype(np.float32))


def refine_records(scene, caster, sources: GatherSources, cache: IrradianceCache, zones: Zones,
                   settings: BakeSettings, params: CacheParameters, executor: Executor,
                   progress: Progress | None = None, stream: int = STREAM_REFINE) -> tuple[IrradianceCache, dict]:
    """Refined copy of ``cache`` and counters (rays cast, virtual rays, cells filled by them): every
    record gathers once, the noisy ones again (deviation: adaptive-gathering, :class:`Gathers`)."""
    K = len(cache)
    if K == 0:
        return cache, {}
    H = Hemisphere(settings.hemisphere_theta, settings.hemisphere_phi)
    serial = caster.serial()
    r_floor = CELL_DISTANCE_FLOOR * params.a * params.R_min

    def run(index, s, round=0, records=None):
        """Batch ``index``: records s, or with ``records`` (a later round) records[s]."""
        rng = np.random.default_rng([settings.seed, stream, index] + ([round] if round else []))
        rows = s if records is None else records[s]
        lengths, photons = zones.batch(s) if records is None else zones.subset(rows)
        # A later round casts real rays into every cell: the photons would lend it the same virtual rays.
        return refine_batch(scene, serial, sources, cache.p[rows], cache.n[rows], lengths, photons, H,
                            settings.reuse_photon_paths and not round, rng, r_floor, cache.hole[rows], params.R_min)

    batches = slices(K, RECORD_BATCH)
    results = executor.map_chunks(run, batches, progress)
    gathers = Gathers(K, 3 if sources.sky is None else 6)
    counters = {key: 0 for key in COUNTERS}
    for s, r in zip(batches, results):
        gathers.add(s, r, counters)
    stage = progress.stage if progress is not None else ""
    # deviation: adaptive-gathering, docs/DEVIATIONS.md
    for round in range(1, GATHER_ROUNDS if settings.deviations.adaptive_gathering else 1):
        noisy = gathers.noisy()
        if len(noisy) == 0:
            break
        if progress is not None:
            progress.begin(f"{stage}: {len(noisy):,} noisy records gather again")
        batches = slices(len(noisy), RECORD_BATCH)
        results = executor.map_chunks(partial(run, round=round, records=noisy), batches, progress)
        for s, r in zip(batches, results):
            gathers.add(noisy[s], r, counters)
        counters["refine_extra_gathers"] += len(noisy)
    if progress is not None and counters["refine_extra_gathers"]:
        progress.begin(stage)  # what follows (the zones' walls) is the stage's, not the last round's
    refined = cache.take(slice(None))
    E, grad_r, grad_t, R = gathers.means()
    refined.refined[:] = True
    counters["refine_wall_rays"] = 0
    if settings.deviations.gathered_radius:  # deviation: gathered-radius, docs/DEVIATIONS.md
        refined.R = np.clip(R, params.R_min, params.R_max)
        if params.neighbour_clamp:  # deviation: neighbour-clamp, docs/DEVIATIONS.md
            refined.R = neighbour_clamp(refined.p, refined.R, executor.workers)
        # The zones changed size: find their walls again (one ray per sector and record).
        if params.wall_sectors:  # deviation: wall-sectors, docs/DEVIATIONS.md
            refined.wall = wall_distances(caster, refined.p, refined.n, params.a * refined.R)
            counters["refine_wall_rays"] = refined.wall.size
        else:
            refined.wall = open_walls(K)
    # deviation: record-validity, docs/DEVIATIONS.md. After the neighbour clamp, which would shrink the
    # zones around it too.
    refined.R = np.where(gathers.inside, INSIDE_RECORD_RADIUS * params.R_min, refined.R)
    if settings.deviations.gradient_limiting:  # deviation: gradient-limiting, docs/DEVIATIONS.md
        grad_t, grad_r = limit_gradients(E, grad_t, grad_r, params.a * refined.R)
    refined.E, refined.grad_r, refined.grad_t = E[:, :3], grad_r[:, :3], grad_t[:, :3]
    if sources.sky is not None:  # deviation: sky-gathering, docs/DEVIATIONS.md
        refined.E_sky, refined.grad_r_sky, refined.grad_t_sky = E[:, 3:], grad_r[:, 3:], grad_t[:, 3:]
    caster.rays_cast += counters["refine_rays_cast"] + counters["refine_shadow_rays"]
    return refined, counters


class Gathers:
    """Sums over each record's gathers: one each, and up to GATHER_ROUNDS for the noisy ones
    (deviation: adaptive-gathering). ``add`` takes a :func:`refine_batch` result for records ``index``.

    The first gather reuses photon paths; the later ones cast a real ray into every cell, so their
    average also shrinks the virtual rays' photon noise, which a repeated reuse would read again.
    """

    def __init__(self, K: int, channels: int = 3):
        self.n = np.zeros(K)
        self.E = np.zeros((K, channels))
        self.grad_r, self.grad_t = np.zeros((K, channels, 3)), np.zeros((K, channels, 3))
        self.inv_R, self.variance, self.R_first = np.zeros(K), np.zeros(K), np.zeros(K)
        self.inside = np.zeros(K, bool)

    def add(self, index, r: dict, counters: dict):
        first = self.n[index] == 0
        self.R_first[index] = np.where(first, r["R"], self.R_first[index])
        self.n[index] += 1
        self.E[index] += r["E"]
        self.grad_r[index] += r["grad_r"]
        self.grad_t[index] += r["grad_t"]
        with np.errstate(divide="ignore"):
            self.inv_R[index] += 1.0 / r["R"]
        self.variance[index] += r["standard_error"] ** 2
        self.inside[index] |= r["inside"]
        for key in COUNTERS:
            counters[key] += r.get(key, 0)

    def noisy(self) -> np.ndarray:
        """Records whose mean E_k's standard error exceeds GATHER_ERROR of max(E_k, GATHER_DARK mean E)."""
        E = self.E.mean(axis=1) / self.n
        floor = GATHER_DARK * E.mean() if len(E) else 0.0
        error = np.sqrt(self.variance) / self.n
        return np.flatnonzero(error > GATHER_ERROR * np.maximum(E, floor))

    def means(self) -> tuple:
        """(E, grad_r, grad_t, R): the gathers' means, R the harmonic mean of their R; a record any
        gather found inside geometry (deviation: record-validity) keeps E = 0 and no gradients."""
        with np.errstate(divide="ignore"):
            R = np.where(self.n == 1, self.R_first, self.n / self.inv_R)
        lit = np.where(self.inside, 0.0, 1.0 / self.n)
        return self.E * lit[:, None], self.grad_r * lit[:, None, None], self.grad_t * lit[:, None, None], R


def refine_batch(scene, caster, sources: GatherSources, p_k: np.ndarray, n_k: np.ndarray, zone_lengths: np.ndarray,
                 zone_photons: np.ndarray, H: Hemisphere, reuse: bool, rng: np.random.Generator,
                 r_floor: float, hole: np.ndarray | None = None, R_min: float = 0.0) -> dict:
    """Figure 4 for B records: probe, virtual rays, real rays for empty cells, then E_k and gradients.

    hole : (B,) bool, the hole records (placed at texel samples; only they can be found inside geometry).
    R_min : the cache's; a photon that sees a hole record within half of it proves the record is
        not inside geometry (deviation: photon-evidence).
    """
    B = len(p_k)
    t1, t2, n = local_frames(n_k)
    frames = (p_k, t1, t2, n)
    sums = CellSums(B, H, sources.sky is not None)
    probe_rays = visibility_rays = path_rays = virtual = cells_virtual = 0
    zone_radius = np.full(B, np.inf)
    hits = []
    if reuse and sources.deviations.probe_rays:
        zone_radius, probe_rays, probe_hits = probe(caster, frames, sums, rng)
        hits.append(probe_hits)
    if reuse:
        virtual, cells_virtual, visibility_rays, path_rays = fill_virtual(caster, sources, frames, zone_lengths,
                                                                          zone_photons, zone_radius, sums, rng)
    empty = sums.empty_cells()  # Figure 4c: real rays for the cells no ray reached
    hits.append(trace_real(caster, frames, empty, sums, rng, sources.sky)[0])
    real = RealHits.concatenate(hits)
    shadow_rays, gap_hits = shade_real(scene, caster, sources, real, sums, rng, n)
    for beyond, weight in through_glass(caster, real, sums, sources.sky):  # deviation: transparent-shadows
        more_rays, more_gap = shade_real(scene, caster, sources, beyond, sums, rng, n, weight)
        shadow_rays, gap_hits = shadow_rays + more_rays, gap_hits + more_gap
    E, grad_r, grad_t, R = sums.irradiance_and_gradients(t1, t2, n, r_floor)
    inside = np.zeros(B, bool)
    # deviation: record-validity, docs/DEVIATIONS.md
    if sources.deviations.record_validity and hole is not None and hole.any():
        real_rays = np.bincount(empty // H.cells, minlength=B) + probe_rays // max(B, 1)
        inside = record_inside_geometry(caster, real, H.cells, real_rays,
                                        open_backs(caster, sources.density, sources.deviations)) & hole
        if sources.deviations.photon_evidence:  # deviation: photon-evidence, docs/DEVIATIONS.md
            overrule_by_photons(inside, caster, sources.density, p_k, n_k, R_min)
        E[inside], grad_r[inside], grad_t[inside] = 0.0, 0.0, 0.0
    return {
        "E": E, "grad_r": grad_r, "grad_t": grad_t, "R": R,
        "standard_error": np.where(inside, 0.0, sums.standard_error()), "inside": inside,
        "refine_rays_cast": len(empty) + probe_rays + visibility_rays + path_rays + sums.glass_rays,
        "refine_probe_rays": probe_rays,
        "refine_visibility_rays": visibility_rays,
        "refine_path_visibility_rays": path_rays,
        "refine_shadow_rays": shadow_rays,
        "refine_gap_hits": gap_hits,
        "refine_virtual_rays": virtual,
        "refine_cells_virtual": cells_virtual,
        "refine_cells": B * H.cells,
        "refine_records_inside": int(inside.sum()),
    }


def record_inside_geometry(caster, real: RealHits, cells: int, real_rays: np.ndarray,
                           open_back: np.ndarray | None = None) -> np.ndarray:
    """(B,) bool: records whose real gathering rays (``real_rays`` (B,) cast each) mostly hit back faces.

    Texel validity's test (:mod:`core.validity`, BACKFACE_FRACTION) with the hundreds of rays a
    record casts instead of a texel sample's eight: hole records placed at samples that passed the
    eight-ray vote inside a wall's hollow gathered the back faces' light where a path tracer finds
    none (the occluded building flags 105 of its 923). Only hole records are asked: a pass-2 record
    stands where a photon arrived, which proves light reaches it (a lamp inside a box whose normals
    face out lights the box's inside). Records with fewer than VALIDITY_RAYS real rays (photons lent
    the rest) are left alone. open_back : as :func:`core.validity.inside_geometry`'s.
    """
    back = closed_backs(caster.face_normals, real.triangle, real.direction, open_back)
    back_hits = np.bincount(real.cell[back] // cells, minlength=len(real_rays))
    return (real_rays >= VALIDITY_RAYS) & (back_hits > BACKFACE_FRACTION * real_rays)


def probe(caster, frames, sums: CellSums, rng: np.random.Generator) -> tuple[np.ndarray, int, RealHits]:
    """PROBE_RAYS real rays per record, stratified over the hemisphere; they fill their cells.

    deviation: probe-rays, docs/DEVIATIONS.md. Their harmonic-mean distance R_probe bounds the
    photons that may lend virtual rays (within VIRTUAL_RADIUS R_probe): beside a wall the
    record's view differs from its neighbours' a few centimetres away, and Figure 3's R_k (from
    photon last hits) tends to miss that wall. Returns (zone radius (B,), rays, their hits, shaded
    later with the batch's other real rays).
    """
    B, C = sums.B, sums.H.cells
    probe_cells = np.unique(np.linspace(0, C - 1, PROBE_RAYS).astype(np.int64))
    cells = (np.arange(B)[:, None] * C + probe_cells[None, :]).ravel()
    hits, inv_sum, inv_n = trace_real(caster, frames, cells, sums, rng)
    R_probe = np.divide(inv_n, inv_sum, out=np.full(B, np.inf), where=inv_sum > 0)
    return VIRTUAL_RADIUS * R_probe, len(cells), hits
