"""Texel samples in crevices gather their own irradiance (deviation: crevice-records).

docs/DEVIATIONS.md, switch ``Deviations.crevice_records``. Records lie about a zone apart (a R_min at
least: R_k is clamped there so their count stays bounded), and Equation 3 carries their E_k over
that distance. Where other surfaces stand near a texel (the 2 cm between window tracery and its
wall, the crease under a parapet's overhang, a capital's carving, a corner) indirect light changes
faster than the records are spaced and no record nearby holds the texel's: the cathedral's 5 % of
texels nearest other surfaces held half of its light map's systematic error, some 0.4-2x a path
tracer.
Such a texel sample gets a record of its own, gathered by pass 3's final gathering on a coarser
hemisphere, whose E_k it takes instead of Equation 3's (and no hole record is placed for it). The
records are the sample's only: they join no lookup, so the cache stays as the paper builds it. A
record that finds itself inside geometry (record-validity, its rays mostly meeting back faces: the
eight vote rays of texel validity said otherwise) leaves its sample dark.

The test is the harmonic mean distance of a few rays from the sample, the quantity R_k is (Figure
3): below CREVICE_DISTANCE x a R_min the sample lies in a crevice, unless it is below CREVICE_OFFSETS
ray offsets, nearer than the record's own rays can tell (:func:`crevice_samples`).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from .constants import (CREVICE_CONE, CREVICE_DISTANCE, CREVICE_HEMISPHERE, CREVICE_OFFSETS, CREVICE_RAYS,
                        STREAM_CREVICE_REFINE)
from .executor import TEXEL_CHUNK, slices
from .interpolation import texel_values
from .irradiance_cache import IrradianceCache, Zones
from .refinement import refine_records
from .sampling import pattern_directions


def _pattern() -> np.ndarray:
    """(CREVICE_RAYS, 3) z-up directions: the normal, and the rest evenly round a cone CREVICE_CONE from it."""
    k = CREVICE_RAYS - 1
    phi = 2 * np.pi * np.arange(k) / k
    cone = np.radians(CREVICE_CONE)
    ring = np.stack([np.sin(cone) * np.cos(phi), np.sin(cone) * np.sin(phi), np.full(k, np.cos(cone))], axis=1)
    return np.concatenate([[[0.0, 0.0, 1.0]], ring])


def local_distance(caster, p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(m,) harmonic mean distance of a fixed pattern of rays (:func:`_pattern`, in each point's tangent
    frame) from points p facing n (m, 3); a ray that escapes counts as infinitely far (inf where all do).

    Fixed, not random: the same geometry gives the same verdict at any scale, seed or target order (a
    random pattern drawn from a target's content-keyed stream would not), and neighbouring samples agree."""
    return _harmonic(_inverse_distances(caster, p, n))


def _harmonic(inverse: np.ndarray) -> np.ndarray:
    """(m,) CREVICE_RAYS over each row's sum of inverse distances (m, CREVICE_RAYS); inf where it is 0.
    The one way :func:`local_distance` and the bounds of :func:`in_crevice` sum them: a float sum of
    non-negative terms summed in one order only grows when a term grows, so the bounds hold exactly."""
    total = inverse.sum(axis=1)
    return np.divide(inverse.shape[1], total, out=np.full(len(total), np.inf), where=total > 0)


def _inverse_distances(caster, p: np.ndarray, n: np.ndarray, reach: float | None = None) -> np.ndarray:
    """(m, CREVICE_RAYS) 1 / hit distance of :func:`_pattern`'s rays from points p facing n (m, 3), 0 where a
    ray escapes; with ``reach``, rays end there and NaN marks those that met nothing nearer (unknown)."""
    pattern = _pattern()
    rays = len(pattern)
    origin = np.repeat(p, rays, axis=0)
    normal = np.repeat(n, rays, axis=0)
    d = pattern_directions(pattern, n).reshape(-1, 3)  # one frame per point, not per ray
    hits = caster.intersect(origin, d, normals=normal, unit=True, t_max=reach)
    missed = 0.0 if reach is None else np.nan
    return np.where(hits.hit, 1.0 / np.maximum(hits.t, 1e-30), missed).reshape(len(p), rays)


def in_crevice(caster, p: np.ndarray, n: np.ndarray, nearer: float, farther: float) -> tuple[np.ndarray, int]:
    """((m,) bool: points p facing n (m, 3) whose :func:`local_distance` H has farther <= H < nearer, rays cast).

    The verdict full-length rays give, from rays CREVICE_RAYS x ``nearer`` long: most samples stand in
    the open, where full-length rays cross the scene (Sponza 16 texels/m: the test's CPU 3.8-4.4 -> 2.7-3.3
    s). A ray that meets nothing within reach adds between 0 and 1 / reach to the sum of inverse
    distances, which bounds H; the few points whose bounds straddle a threshold cast their rays again in
    full."""
    reach = CREVICE_RAYS * nearer
    inverse = _inverse_distances(caster, p, n, reach)
    unknown = np.isnan(inverse)
    high = _harmonic(np.where(unknown, 0.0, inverse))  # H if every unknown ray escaped
    low = _harmonic(np.where(unknown, 1.0 / reach, inverse))  # ... if each met a face just past reach
    crevice = (high < nearer) & (low >= farther)
    settled = ((high < nearer) | (low >= nearer)) & ((low >= farther) | (high < farther))
    again = np.flatnonzero(~settled)
    rays = inverse.size
    if len(again):
        H = _harmonic(_inverse_distances(caster, p[again], n[again]))
        crevice[again] = (H < nearer) & (H >= farther)
        rays += len(again) * CREVICE_RAYS
    return crevice, rays


def crevice_samples(caster, p: np.ndarray, n: np.ndarray, params, executor, progress) -> tuple[np.ndarray, int]:
    """(indices of the points p facing n (m, 3) that lie in crevices: :func:`local_distance` below
    CREVICE_DISTANCE x a R_min, but not below CREVICE_OFFSETS ray offsets; rays cast), chunked over the
    executor (:func:`in_crevice`).

    A surface within two offsets of the point is nearer than its gathering rays can tell: they leave
    the surface an offset off it (Sponza held: 159 such samples gathered 2.9-3.6 E/pi where a path
    tracer finds 0.1-1.9); those keep Equation 3."""
    serial = caster.serial()
    nearer, farther = CREVICE_DISTANCE * params.a * params.R_min, CREVICE_OFFSETS * caster.epsilon
    parts = executor.map_chunks(lambda index, s: in_crevice(serial, p[s], n[s], nearer, farther),
                                slices(len(p), TEXEL_CHUNK), progress)
    crevice = np.concatenate([c for c, _ in parts]) if parts else np.zeros(0, bool)
    rays = sum(r for _, r in parts)
    caster.rays_cast += rays
    return np.flatnonzero(crevice), rays


def crevice_irradiance(scene, caster, sources, p: np.ndarray, n: np.ndarray, params, settings, executor,
                       progress) -> tuple[np.ndarray, dict]:
    """(E (m, 3), or (m, 6) with the sky's channels when ``sources`` gather it; refinement counters) at
    points p facing n (m, 3): each one's own record, gathered as pass 3's over a CREVICE_HEMISPHERE
    hemisphere."""
    m = len(p)
    records = IrradianceCache(p=p, n=n, E=np.zeros((m, 3)), R=np.full(m, params.R_min),
                              grad_r=np.zeros((m, 3, 3)), grad_t=np.zeros((m, 3, 3)),
                              photons_used=np.zeros(m, np.int32), hole=np.ones(m, bool), refined=np.zeros(m, bool))
    theta, phi = CREVICE_HEMISPHERE
    # No zone photons (no virtual rays: every cell casts a real ray), no new R_k or walls (the record is
    # read at its own point only) and one gather: adaptive gathering's second rounds cost Sponza held
    # 12 CPU s for 0.02 point of error.
    own = replace(settings, hemisphere_theta=theta, hemisphere_phi=phi,
                  deviations=replace(settings.deviations, gathered_radius=False, adaptive_gathering=False))
    refined, counters = refine_records(scene, caster, sources, records, Zones([np.zeros(0, np.int32)] * m), own,
                                       params, executor, progress, stream=STREAM_CREVICE_REFINE)
    return texel_values(refined, sources.sky is not None)[0], counters
