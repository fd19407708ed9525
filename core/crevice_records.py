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
from .sampling import to_world


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
    pattern = _pattern()
    rays = len(pattern)
    origin = np.repeat(p, rays, axis=0)
    normal = np.repeat(n, rays, axis=0)
    d = to_world(np.tile(pattern, (len(p), 1)), normal)
    hits = caster.intersect(origin, d, normals=normal, unit=True)
    inverse = np.where(hits.hit, 1.0 / np.maximum(hits.t, 1e-30), 0.0).reshape(len(p), rays).sum(axis=1)
    return np.divide(rays, inverse, out=np.full(len(p), np.inf), where=inverse > 0)


def crevice_samples(caster, p: np.ndarray, n: np.ndarray, params, executor, progress) -> tuple[np.ndarray, int]:
    """(indices of the points p facing n (m, 3) that lie in crevices: :func:`local_distance` below
    CREVICE_DISTANCE x a R_min, but not below CREVICE_OFFSETS ray offsets; rays cast), chunked over the
    executor.

    A surface within two offsets of the point is nearer than its gathering rays can tell: they leave
    the surface an offset off it (Sponza held: 159 such samples gathered 2.9-3.6 E/pi where a path
    tracer finds 0.1-1.9); those keep Equation 3."""
    serial = caster.serial()
    parts = executor.map_chunks(lambda index, s: local_distance(serial, p[s], n[s]), slices(len(p), TEXEL_CHUNK),
                                progress)
    distance = np.concatenate(parts) if parts else np.zeros(0)
    rays = len(p) * CREVICE_RAYS
    caster.rays_cast += rays
    near = (distance < CREVICE_DISTANCE * params.a * params.R_min) & (distance >= CREVICE_OFFSETS * caster.epsilon)
    return np.flatnonzero(near), rays


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
