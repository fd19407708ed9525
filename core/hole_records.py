"""Indirect light at texel samples: Equation 3 over the cache, with hole records (section 3.4).

Samples no record accepts first try, where hole records are estimated from photons (Preview, photon-path
reuse), the zones widened by GAP_TEXELS texels (deviation: gap-fill); samples still uncovered, and in
the first round samples whose records' weights sum below THIN_COVERAGE / a (deviation: thin-coverage),
get new records placed on them (Algorithm 1's hole entry point,
:func:`~core.irradiance_cache.cache_for_holes`), refined like pass 3's records at Final quality;
HOLE_ROUNDS rounds of that (deviation: hole-rounds), then the nearest record's irradiance for what
is still uncovered (deviation: nearest-record-fallback). A record off a
sample's tangent plane counts only if it sees the sample, in every lookup and in the fallback
(deviation: record-visibility). At Final, samples in crevices gather records of their own
instead of all of this (deviation: crevice-records, :mod:`core.crevice_records`).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from .constants import (FINE_ZONE_TEXELS, GAP_TEXELS, NEAREST_RECORDS, STREAM_HOLE_ORDER, STREAM_REFINE_HOLES,
                        STREAM_SKY, THIN_COVERAGE)
from .crevice_records import crevice_irradiance, crevice_samples
from .density import PhotonDensity
from .executor import Beside, Executor, Progress, row_chunks
from .interpolation import interpolate, texel_values
from .irradiance_cache import CacheParameters, IrradianceCache, cache_for_holes
from .refinement import GatherSources, refine_records
from .settings import BakeSettings
from .sky_gathering import gather_sky
from .validity import sample_validity
from .zone_grid import SharedZones


@dataclass(frozen=True)
class TexelVerdicts:
    """What a target's texel samples are, before any record is read: inside (n,) bool, inside geometry; weights
    (n,), each sample's share of its texel's indirect light (:func:`core.validity.indirect_weights`);
    crevice (c,) int64, the samples that gather their own record (deviation: crevice-records; empty
    without it or at Preview); crevice_rays, the rays that test cast."""

    inside: np.ndarray
    weights: np.ndarray
    crevice: np.ndarray
    crevice_rays: int


def texel_verdicts(scene, caster, density: PhotonDensity, target_index: int, points, texel_size: float, stream: int,
                   params: CacheParameters, settings: BakeSettings, executor: Executor, progress: Progress, stats,
                   contact=None, centre_triangle: np.ndarray | None = None) -> TexelVerdicts:
    """Texel validity (:func:`core.validity.sample_validity`) and, at Final, which valid samples lie in crevices
    (:func:`core.crevice_records.crevice_samples`): they need the photons, not the records, so a bake runs them
    beside pass 2 where a core is free (:func:`core.pipeline.indirect_at_targets`). Arguments as
    :func:`indirect_at_texels`."""
    inside, weights = sample_validity(scene, caster, density, target_index, points, texel_size, stream, params.R_min,
                                      settings, executor, progress, stats, contact=contact,
                                      centre_triangle=centre_triangle)
    crevice, rays = np.zeros(0, np.int64), 0
    if settings.refine and settings.deviations.crevice_records:  # deviation: crevice-records
        with stats.stage("validity"):
            progress.begin("Texel samples in crevices")
            valid = np.flatnonzero(~inside)
            found, rays = crevice_samples(caster, points.p[valid], points.n_geometric[valid], params, executor,
                                          progress)
            crevice = valid[found]
    return TexelVerdicts(inside, weights, crevice, rays)


def indirect_at_texels(scene, caster, density: PhotonDensity | None, sources: GatherSources | None,
                       cache: IrradianceCache, target_index: int, points, texel_size: float, stream: int,
                       params: CacheParameters, settings: BakeSettings, executor: Executor, progress: Progress,
                       stats, sky: np.ndarray | None = None, contact=None, centre_triangle: np.ndarray | None = None,
                       verdicts: TexelVerdicts | None = None, shared: SharedZones | None = None
                       ) -> tuple[np.ndarray, IrradianceCache, np.ndarray]:
    """Texel validity, then Equation 3 with hole records for one target: (E (n, 3), its hole records,
    the samples' shares of their texels' indirect light (n,), :func:`core.validity.indirect_weights`).

    target_index : the target's index in ``scene.targets``; points : its
    :class:`~core.texels.TexelPoints`; texel_size : world size of one texel.
    sources : what refining hole records reads (Final quality), None for Preview.
    sky : the world's radiance (3,) when the records gather it (deviation: sky-gathering,
        :mod:`core.sky_gathering`): E is then (n, 6), the records' sky in channels 3-5; or None.
    contact : :class:`core.contact.ContactFaces` for texel validity (deviation: contact-faces), or None.
    centre_triangle : the target's :attr:`core.texels.TargetRaster.centre_triangle` for texel validity, or None.
    verdicts : the target's :func:`texel_verdicts`, computed already (beside pass 2), or None.
    shared : the bake's zone grid over ``cache``, which every target's lookups share (:class:`SharedZones`), or None.
    """
    if density is None or len(points) == 0:  # no records: the sky stays the texels' own (3 channels)
        return np.zeros((len(points), 3)), IrradianceCache(), points.weight.astype(np.float64)
    E = np.zeros((len(points), 3 if sky is None else 6))
    if verdicts is None:
        verdicts = texel_verdicts(scene, caster, density, target_index, points, texel_size, stream, params, settings,
                                  executor, progress, stats, contact, centre_triangle)
    weights, crevice = verdicts.weights, verdicts.crevice
    outside = ~verdicts.inside
    outside[crevice] = False  # a mask, not np.setdiff1d: that sorts every sample's index (11 M at 2048^2)
    valid = np.flatnonzero(outside)
    del outside
    with stats.stage("interpolate"):
        crevice_counters = {"crevice_samples": len(crevice), "crevice_distance_rays": verdicts.crevice_rays}
        gathering = _CreviceGathering(scene, caster, sources, points.p[crevice], points.n_shading[crevice], params,
                                      settings, executor, progress)
        try:
            progress.begin("Interpolating the cache at texels")
            merged, sample_to_point = points.per_texel(valid)  # inside samples not averaged in
            filled = fill_holes(scene, caster, density, sources, cache, merged, params, settings, executor, progress,
                                texel_size, sky, shared)
            for s in row_chunks(len(valid)):  # each sample its texel's value, in passes (no whole-array temporary)
                E[valid[s]] = np.take(filled.E, sample_to_point[s], axis=0)
            fine = _fine_samples(filled.smallest, sample_to_point, texel_size, settings)
            if len(fine):
                progress.begin(f"Interpolating the cache at {len(fine):,} texel samples in small zones")
                samples = valid[fine]  # the small-zone samples' indices into ``points``
                E_fine, w_fine = interpolate(filled.cache, params.a, settings.gradients, points.p, points.n_shading,
                                             executor, progress, caster=_record_visibility(caster, params),
                                             sky=sky is not None, layers=settings.refine, shared=shared, rows=samples)
                _write_fine(E, samples, E_fine, w_fine)
        except BaseException:
            gathering.stop()
            raise
        if len(crevice):
            progress.begin(f"Gathering at {len(crevice):,} texel samples in crevices")
            E[crevice], refined = gathering()
            crevice_counters.update({f"crevice_{key}": value for key, value in refined.items()})
    stats.add(texel_points_interpolated=len(merged) + len(fine), texel_points_unfilled=filled.unfilled,
              **{f"holes_{key}": value for key, value in filled.counters.items()}, **crevice_counters)
    return E, filled.cache.take(slice(len(cache), None)), weights


class _CreviceGathering:
    """:func:`~core.crevice_records.crevice_irradiance` at the crevice samples p facing n (m, 3), started on a
    thread of its own (:class:`~core.executor.Beside`) that runs its chunks on the bake's workers while
    the calling thread fills the other samples' holes: neither needs the other's results, and the holes'
    serial stretches (Algorithm 1 over the uncovered samples, the zone grids) leave a worker idle. Calling
    it waits and returns (E, counters); :meth:`stop` ends it early. On one worker or a Dask cluster it
    runs when called. Its chunks draw their own random streams, so it computes what it would in line."""

    def __init__(self, scene, caster, sources, p, n, params, settings, executor, progress):
        self.caster, self.progress = caster, progress
        self.compute = lambda view, progress: crevice_irradiance(scene, view, sources, p, n, params, settings,
                                                                 executor, progress)
        self.out, self.side = [], None
        if len(p) and executor.in_process and executor.workers > 1:
            self.view = copy.copy(caster)  # the same BVH and workers; its rays count apart (two threads add)
            self.view.rays_cast = 0
            own = Progress()  # silent: the calling thread reports the texels' stage
            self.side = Beside(lambda: self.out.append(self.compute(self.view, own)), own, progress)
            self.side.start()

    def __call__(self) -> tuple[np.ndarray, dict]:
        if self.side is None:
            return self.compute(self.caster, self.progress)
        self.side.wait()
        self.caster.rays_cast += self.view.rays_cast
        return self.out[0]

    def stop(self) -> None:
        if self.side is not None:
            self.side.stop()


def _record_visibility(caster, params: CacheParameters):
    """The caster lookups test record visibility with (deviation: record-visibility), or None."""
    return caster if params.record_visibility else None


def _write_fine(E: np.ndarray, samples: np.ndarray, E_fine: np.ndarray, w_fine: np.ndarray) -> None:
    """E[samples] = E_fine where a record covered the sample (w_fine > 0); the others keep their texel's value.
    In place, E_fine included: no copy of millions of rows. samples : (f,) distinct rows of E."""
    uncovered = np.flatnonzero(~(w_fine > 0))
    E_fine[uncovered] = E[samples[uncovered]]
    E[samples] = E_fine


def _fine_samples(smallest, sample_to_point, texel_size, settings) -> np.ndarray:
    """Samples whose texel lies in a zone narrower than FINE_ZONE_TEXELS texels (deviation: fine-zones).

    smallest : (m,) the smallest zone radius a R_k accepted at each merged point (inf: none).
    There Equation 3 changes inside a texel (zone edges are steps), so every sample gets its own
    lookup, as a 2x2 box filter would, instead of the texel's centroid value. Final only: at Preview
    nearly every texel lies in such a zone, and looking its samples up again took a quarter of Sponza's
    Preview time for 3 % of its error (docs/DEVIATIONS.md).
    """
    if not (settings.deviations.fine_zones and settings.refine):
        return np.zeros(0, np.int64)
    return np.flatnonzero((smallest < FINE_ZONE_TEXELS * texel_size)[sample_to_point])


@dataclass(frozen=True)
class _Placed:
    """Records' positions p (K, 3) and radii R (K,): the records placed before a round of hole records."""

    p: np.ndarray
    R: np.ndarray

    def __len__(self) -> int:
        return len(self.p)


class _GrowingCache:
    """The cache and the hole records each round appends, joined into one cache only where every column is
    read (the lookups past the zones, the fallback, the result): the next round's placement reads positions
    and radii alone. A copy of the whole cache per round and target cost a bake of 304 objects 3.6 s."""

    def __init__(self, cache: IrradianceCache):
        self.base, self.added, self._joined = cache, [], cache

    def append(self, new: IrradianceCache) -> None:
        self.added.append(new)
        self._joined = None

    def placed(self) -> "_Placed | IrradianceCache":
        """Every record's position and radius, what neighbour clamping reads of the records placed before
        (the cache itself, not a copy, before any round appended)."""
        if not self.added:
            return self.base
        parts = [self.base, *self.added]
        return _Placed(np.concatenate([c.p for c in parts]), np.concatenate([c.R for c in parts]))

    def joined(self) -> IrradianceCache:
        if self._joined is None:
            self._joined = IrradianceCache.concatenate([self.base, *self.added])
        return self._joined


@dataclass
class FilledLookup:
    """Equation 3 at texel points over the cache and its hole records (what :func:`fill_holes` returns)."""

    E: np.ndarray
    """(m, 3) float64 irradiance, W/m^2 (the nearest record's where no record accepts the point); (m, 6)
    with the gathered sky (deviation: sky-gathering)."""
    w: np.ndarray
    """(m,) float64 Ward weight sums; 0 where no record accepts the point."""
    smallest: np.ndarray
    """(m,) float64 the smallest zone radius a R_k accepted at each point, scene units (inf: none)."""
    cache: IrradianceCache
    """The cache with the hole records appended."""
    hole_records: int
    unfilled: int
    """Points no record accepts after the hole rounds."""
    counters: dict = field(default_factory=dict)
    """The hole records' refinement counters (:data:`core.refinement.COUNTERS`), summed over the rounds."""


def interpolate_filling_holes(scene, caster, density: PhotonDensity, sources: GatherSources | None,
                              cache: IrradianceCache, points, params: CacheParameters, settings: BakeSettings,
                              executor: Executor, progress: Progress):
    """Equation 3 at every texel sample; samples no record covers get new records (section 3.4).

    Returns (E (m, 3), the cache with the hole records appended, hole records, samples left unfilled).
    """
    filled = fill_holes(scene, caster, density, sources, cache, points, params, settings, executor, progress)
    return filled.E, filled.cache, filled.hole_records, filled.unfilled


def fill_holes(scene, caster, density: PhotonDensity, sources: GatherSources | None, cache: IrradianceCache,
               points, params: CacheParameters, settings: BakeSettings, executor: Executor,
               progress: Progress, texel_size: float = 0.0, sky: np.ndarray | None = None,
               shared: SharedZones | None = None) -> FilledLookup:
    """:func:`interpolate_filling_holes`, with the weights and smallest zones at every point.

    texel_size : world size of one texel; points no zone accepts first try zones widened by
    GAP_TEXELS of it, unless hole records gather (deviation: gap-fill; 0 skips that).
    sky : the world's radiance (3,): interpolate the records' gathered sky too (E (m, 6),
        :attr:`core.interpolation.CacheLookup.sky`); Preview's hole records gather it (:func:`_hole_records`).
    shared : the bake's zone grid over ``cache`` (:class:`~core.zone_grid.SharedZones`), or None.
    Equation 3 runs once over all points and, after each round of hole records, again at the
    points that were holes, over that round's records (every older one refused those points);
    covered points keep the records they had (the smallest zones there leave hole records out).
    """
    seeing = _record_visibility(caster, params)

    def lookup(c, index, caster=seeing, margin=0.0):
        return interpolate(c, params.a, settings.gradients, points.p[index], points.n_shading[index], executor,
                           progress, with_zone=True, caster=caster, margin=margin, sky=sky is not None,
                           layers=settings.refine, shared=shared)

    E, w, smallest = lookup(cache, slice(None))
    hole_records, counters, grown = 0, {}, _GrowingCache(cache)
    gathered = _gathers_hole_records(settings)
    # deviation: thin-coverage, docs/DEVIATIONS.md: Final's hole records, gathered by standard gathering
    # (refined by photon-path reuse they read their zones' few photons: the Cornell box 6.6 -> 7.5 %)
    thin_coverage = settings.deviations.thin_coverage and gathered
    # deviation: gap-fill, docs/DEVIATIONS.md: where hole records are estimated from photons. A hole record
    # gathered at the sample beats a refined record read past its zone, where gaps open (near other
    # surfaces) and the light changes fastest.
    gap_fill = settings.deviations.gap_fill and texel_size > 0 and not gathered
    for round_ in range(settings.deviations.hole_rounds):  # deviation: hole-rounds, docs/DEVIATIONS.md
        holes = np.flatnonzero(w <= 0)
        thin = np.zeros(0, np.int64)
        if round_ == 0 and thin_coverage:
            thin = np.flatnonzero((w > 0) & (w < THIN_COVERAGE / params.a))
            counters["thin_samples"] = len(thin)
        if len(holes) == 0 and len(thin) == 0:
            break
        progress.check()
        if gap_fill:
            E_g, w_g, z_g = lookup(grown.joined(), holes, caster=caster, margin=GAP_TEXELS * texel_size)
            gap = w_g > 0
            E[holes[gap]], w[holes[gap]], smallest[holes[gap]] = E_g[gap], w_g[gap], z_g[gap]
            holes = holes[~gap]
            if len(holes) == 0 and len(thin) == 0:
                break
        asked = np.concatenate([holes, thin])
        progress.begin(f"Hole records, round {round_ + 1}: placing records at {len(asked):,} texel samples")
        new, refined = _hole_records(scene, caster, density, sources, grown.placed(), points.p[asked],
                                     points.n_shading[asked], params, settings, executor, progress, round_, sky, shared)
        if len(new) == 0:
            break
        progress.begin(f"Hole records, round {round_ + 1}: interpolating {len(new):,} records at texel samples")
        hole_records += len(new)
        for key, value in refined.items():
            counters[key] = counters.get(key, 0) + value
        grown.append(new)
        # Every record before this round refused the holes (each pair's test is its own), so Equation 3 over
        # the new records alone is the sum over all, term for term: no zone grid over the whole cache. The
        # thin points add the new records' sums to those of the records that accepted them.
        E_new, w_new, z_new = lookup(new, asked)
        E[holes], w[holes], smallest[holes] = E_new[:len(holes)], w_new[:len(holes)], z_new[:len(holes)]
        if len(thin):
            E_t, w_t, z_t = E_new[len(holes):], w_new[len(holes):], z_new[len(holes):]
            w_all = w[thin] + w_t
            E[thin] = (E[thin] * w[thin, None] + E_t * w_t[:, None]) / w_all[:, None]
            w[thin], smallest[thin] = w_all, np.minimum(smallest[thin], z_t)
    unfilled, cache = np.flatnonzero(w <= 0), grown.joined()
    if len(unfilled) and len(cache) and settings.deviations.nearest_record_fallback:
        # deviation: nearest-record-fallback, docs/DEVIATIONS.md (counted in the stats).
        E[unfilled] = nearest_record(cache, points.p[unfilled], points.n_shading[unfilled], seeing, sky is not None)
    return FilledLookup(E, w, smallest, cache, hole_records, len(unfilled), counters)


def _gathers_hole_records(settings: BakeSettings) -> bool:
    """Whether hole records get their E_k from gathering at their own points (Final, standard gathering)
    rather than from the photons around them (Preview; Final's photon-path reuse reads the zone's photons)."""
    return settings.refine and not settings.reuse_photon_paths


def _hole_records(scene, caster, density, sources, placed, cand_p, cand_n, params, settings, executor, progress,
                  round_: int, sky: np.ndarray | None = None, shared: SharedZones | None = None
                  ) -> tuple[IrradianceCache, dict]:
    """One round of section 3.4: Algorithm 1 over the uncovered samples, refined at Final quality (and
    at Preview given ``sky``, gathering the sky, :func:`core.sky_gathering.gather_sky`); and the counters.
    placed : the records placed before (:class:`_Placed`), which neighbour clamping reads."""
    # Refined by standard gathering, a hole record's E_k comes from its rays alone: no density estimate.
    estimate = not _gathers_hole_records(settings)
    new, zones, _ = cache_for_holes(density, cand_p, cand_n, params,
                                    np.random.default_rng([settings.seed, STREAM_HOLE_ORDER, round_]),
                                    existing=placed, caster=caster, estimate=estimate, shared=shared)
    counters = {}
    if settings.refine and len(new):
        progress.begin(f"Hole records, round {round_ + 1}: gathering at {len(new):,} records")
        new, counters = refine_records(scene, caster, sources, new, zones, settings, params, executor, progress,
                                       stream=STREAM_REFINE_HOLES + round_)
    elif not settings.refine and sky is not None:  # deviation: sky-gathering, docs/DEVIATIONS.md
        new, counters["sky_rays"] = gather_sky(caster, new, sky, params.a, params.R_min,
                                               settings.deviations.gradient_limiting, settings.seed,
                                               (STREAM_SKY, 1 + round_), executor, progress)
    return new, counters


def nearest_record(cache: IrradianceCache, p: np.ndarray, n: np.ndarray, caster=None, sky: bool = False
                   ) -> np.ndarray:
    """E (m, 3) of the nearest of the NEAREST_RECORDS nearest records to each point p, n (m, 3) that
    faces the point's side (n_k . n > 0), else 0; with ``caster`` (deviation: record-visibility) the
    nearest that faces it and sees it.
    sky : (m, 6), the record's gathered sky in channels 3-5.

    A record facing the other way lies on another surface's far side: on the cathedral, samples on a
    nave wall's face turned into the closed wall took the records of the same plane's lit side,
    which are coplanar, so no visibility ray tells them apart (E/pi 0.28 where Cycles and a path
    tracer find 0)."""
    values = texel_values(cache, sky)[0]
    k = min(NEAREST_RECORDS, len(cache))
    _, nearest = cKDTree(cache.p).query(p, k=k)
    nearest = np.asarray(nearest).reshape(len(p), k)
    facing = np.einsum("mkj,mj->mk", cache.n[nearest], n) > 0
    usable = facing.copy()
    if caster is not None:
        row, col = np.nonzero(facing)
        usable[row, col] = ~caster.hidden_off_plane(p[row], n[row], cache.p[nearest[row, col]],
                                                    cache.n[nearest[row, col]])
    first = nearest[np.arange(len(p)), np.argmax(usable, axis=1)]
    return np.where(usable.any(axis=1)[:, None], values[first], 0.0)
