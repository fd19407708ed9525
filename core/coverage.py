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

from .constants import COVERAGE_ANGLES, COVERAGE_FLOOR, COVERAGE_LIFT, COVERAGE_RINGS, SAME_SURFACE_COS, SECTOR_OFFSET
from .record_walls import has_walls, past_walls
from .sampling import orthonormal_basis


def surface_coverage(caster, p_k: np.ndarray, n_k: np.ndarray, radius: float, wall: np.ndarray | None) -> float:
    """Share of the Epanechnikov kernel's mass over the disc of ``radius`` that lies on the record's surface.

    Probe points over the disc (equal-area rings, COVERAGE_RINGS x COVERAGE_ANGLES) each cast a
    short ray down onto the tangent plane from just above it; a point counts if it finds surface
    facing like n_k there and is not past a wall. Returns a value in [COVERAGE_FLOOR, 1].
    """
    u, phi = _COVERAGE_U, _COVERAGE_PHI
    t1, t2 = orthonormal_basis(n_k[None])
    offset = (u * radius)[:, None] * (np.cos(phi)[:, None] * t1 + np.sin(phi)[:, None] * t2)
    lift = COVERAGE_LIFT * radius
    m = len(u)
    origin = p_k + offset + lift * n_k
    down = np.broadcast_to(-n_k, (m, 3))
    hits = caster.intersect(origin, down, t_max=np.full(m, lift + radius))
    present = hits.hit.copy()
    if present.any():
        face_n = caster.face_normals[hits.triangle[present]]
        present[present] = face_n @ n_k >= SAME_SURFACE_COS
    if has_walls(wall):
        present &= ~past_walls(wall, offset, n_k)
    return float(max(np.sum(_COVERAGE_KERNEL * present) / np.sum(_COVERAGE_KERNEL), COVERAGE_FLOOR))


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
