"""Surface coverage: the share of a record's disc that is surface (Preview's E_k normalisation).

deviation: surface-coverage, docs/DEVIATIONS.md (switch ``Deviations.surface_coverage``).

Density estimation divides the photons' power by the whole disc of radius a R_k, but photons
land only on surface: on a 4 cm railing bar, a column's flank or a floor's open edge most of
the disc is empty and E_k comes out several times too low. :func:`surface_coverage` measures
the Epanechnikov-weighted share of the disc that is surface facing like n_k (and not past a
record wall); E_k is divided by it instead of 1.
"""
from __future__ import annotations

import numpy as np

from .constants import (COVERAGE_ANGLES, COVERAGE_DEPTH, COVERAGE_FLOOR, COVERAGE_LIFT, COVERAGE_RINGS,
                        SAME_SURFACE_COS, SECTOR_OFFSET)
from .record_walls import beyond_wall
from .sampling import orthonormal_basis


def surface_coverage(caster, p_k: np.ndarray, n_k: np.ndarray, radius: float, wall: np.ndarray | None,
                     lit_back: np.ndarray | None = None) -> float:
    """:func:`surface_coverages` for one record (p_k, n_k (3,), wall (S,) or None)."""
    return float(surface_coverages(caster, p_k[None], n_k[None], np.array([radius], np.float64),
                                   None if wall is None else np.asarray(wall)[None], lit_back)[0])


def surface_coverages(caster, p_k: np.ndarray, n_k: np.ndarray, radius: np.ndarray,
                      wall: np.ndarray | None, lit_back: np.ndarray | None = None) -> np.ndarray:
    """(B,) share of the Epanechnikov kernel's mass over each record's disc that lies on its surface.

    p_k, n_k : (B, 3) records; radius : (B,) disc radii a R_k; wall : (B, S) float32 or None.
    Probe points over each disc (equal-area rings, COVERAGE_RINGS x COVERAGE_ANGLES) cast a
    short ray down onto the tangent plane from just above it to COVERAGE_DEPTH r below it, all in
    one batch; a point counts if it finds surface facing like n_k there and is not past a wall,
    weighted as a photon on that surface is (see below). Values >= COVERAGE_FLOOR (above 1 where
    the surface is tilted or curved: there is more of it than disc).

    lit_back : (T,) bool, triangles photons reached on their back side (PhotonDensity.lit_back_faces).
    A probe that meets such a triangle's back counts it as the side it sees: the wall is lit from
    there (a flipped wall's photons and records all face that way). Other back faces are the inside
    of a solid the probe started in, where no photon lands, and do not count.
    """
    B, m = len(p_k), PROBES
    u, phi = np.tile(_COVERAGE_U, B), np.tile(_COVERAGE_PHI, B)
    rec = np.repeat(np.arange(B), m)
    t1, t2 = orthonormal_basis(n_k)
    n_r = n_k[rec]
    offset = (u * radius[rec])[:, None] * (np.cos(phi)[:, None] * t1[rec] + np.sin(phi)[:, None] * t2[rec])
    lift = COVERAGE_LIFT * radius[rec]
    hits = caster.intersect(p_k[rec] + offset + lift[:, None] * n_r, -n_r, t_max=lift + COVERAGE_DEPTH * radius[rec])
    present = hits.hit.copy()
    cos = np.ones(len(rec))
    if present.any():
        cos[present] = np.einsum("ij,ij->i", caster.face_normals[hits.triangle[present]], n_r[present])
        if lit_back is not None:
            seen_back = present & (cos < 0)
            seen_back[seen_back] = lit_back[hits.triangle[seen_back]]
            cos[seen_back] = -cos[seen_back]
        present[present] = cos[present] >= SAME_SURFACE_COS
    if wall is not None:
        walled = np.flatnonzero(present & np.isfinite(wall).any(axis=1)[rec])
        present[walled] = ~beyond_wall(wall[rec[walled]], offset[walled], n_r[walled])
    # Each probe stands for the surface it found as the photons there are counted: the kernel at
    # the hit's distance from p_k (below the plane, off a curving surface, it is farther than u r),
    # over the surface's own area (1 / cos of its tilt per unit of disc).
    depth = np.where(present, hits.t - lift, 0.0) / radius[rec]
    weight = np.where(present, np.maximum(1.0 - u ** 2 - depth ** 2, 0.0) / np.maximum(cos, SAME_SURFACE_COS), 0.0)
    share = weight.reshape(B, m).sum(axis=1) / np.sum(_COVERAGE_KERNEL)
    return np.maximum(share, COVERAGE_FLOOR)


PROBES = COVERAGE_RINGS * COVERAGE_ANGLES
"""Rays one coverage measurement casts."""


def _coverage_pattern() -> tuple[np.ndarray, np.ndarray]:
    """(u = d / r, angle) of the coverage probes: equal-area rings, every other ring turned half a step."""
    rings = np.sqrt((np.arange(COVERAGE_RINGS) + 0.5) / COVERAGE_RINGS)
    steps = np.arange(COVERAGE_ANGLES) + 0.5 * (np.arange(COVERAGE_RINGS)[:, None] % 2)
    angles = SECTOR_OFFSET + 2 * np.pi * steps / COVERAGE_ANGLES
    return np.broadcast_to(rings[:, None], angles.shape).ravel(), angles.ravel()


_COVERAGE_U, _COVERAGE_PHI = _coverage_pattern()
_COVERAGE_KERNEL = 1.0 - _COVERAGE_U ** 2  # Epanechnikov weight of each probe
