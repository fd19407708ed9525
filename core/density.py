"""Photon density estimation for pass 2: R_k (Figure 3) and the Epanechnikov E_k (section 3.2).

:class:`PhotonDensity` holds the kd-tree over an immutable :class:`~core.photons.PhotonMap` and
answers the two queries of one record creation. It holds nothing computed by later passes.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .constants import COVERAGE_LIFT, R_K_DISTANCE_FLOOR, R_K_SAME_SIDE_COS, R_OVERSAMPLE, SAME_SURFACE_COS, WALL_MASS_FLOOR
from .photons import PhotonMap
from .record_walls import has_walls, past_walls
from .ward import accepted, ward_weight


class PhotonDensity:
    """kd-trees over the photon map answering the two queries of each record creation."""

    def __init__(self, photons: PhotonMap):
        self.photons = photons
        # Memory: the kd-tree keeps the only float64 copy of the positions (tree.data);
        # normals, powers and last hits stay float32 (12 bytes each per photon), so
        # 4M photons fit in 1 GB with their trees (bench/ measures the peak).
        self.tree = cKDTree(photons.p, leafsize=16, balanced_tree=False, compact_nodes=False)
        self.p = self.tree.data
        self.n = photons.n
        self.power = photons.power
        self.has_indirect = bool(photons.is_indirect.any())
        self.last_hit = (photons.p + photons.wi * photons.d_prev[:, None]).astype(np.float32)
        self.is_indirect = photons.is_indirect
        self.queries = 0

    def harmonic_mean_distance(self, p_k: np.ndarray, n_k: np.ndarray, count: int, R_max: float) -> float:
        """R_k from the last hits of the ``count`` nearest indirect photons (Figure 3); R_max if none fit.

        The main tree is asked for R_OVERSAMPLE x ``count`` neighbours and the indirect ones
        on the record's side are kept: a second tree over the indirect photons alone would
        cost ~30 bytes per photon (measured 989 MB peak with it for 4M photons through pass 2).
        """
        if not self.has_indirect:
            return R_max
        k = min(R_OVERSAMPLE * count, len(self.p))
        _, idx = self.tree.query(p_k, k=k)
        self.queries += 1
        idx = np.atleast_1d(idx)
        idx = idx[idx < len(self.p)]
        idx = idx[self.is_indirect[idx]][:count]
        to_hit = self.last_hit[idx].astype(np.float64) - p_k
        # Keep photons on the record's side whose last hit lies above its tangent plane.
        ok = (self.n[idx] @ n_k > R_K_SAME_SIDE_COS) & (to_hit @ n_k > 0)
        if not ok.any():
            return R_max
        d = np.linalg.norm(to_hit[ok], axis=1)
        d = np.maximum(d, R_K_DISTANCE_FLOOR * R_max)
        return float(ok.sum() / np.sum(1.0 / d))

    def record(self, p_k: np.ndarray, n_k: np.ndarray, R_k: float, a: float, wall: np.ndarray | None = None,
               coverage: float | None = None, caster=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """Both photon queries of one record creation, gathering the sphere's photons once.

        Returns (zone, w, E_k, used): the photons of S_{a R_k} that record k contributes
        to (Equation 2) with their Ward weights, the Epanechnikov estimate E_k (3,) and
        the number of indirect photons it used.

        E_k: K(d) = 2 / (pi r^2) * (1 - d^2 / r^2), r = a R_k, integrates to 1 over the
        disc. Photons whose normal disagrees with n_k (n . n_k < SAME_SURFACE_COS: another
        wall of a corner, the far side of a thin wall) are rejected. The selection is by
        distance, not by Ward's weight: the kernel is normalised over the whole disc, and on
        a curved surface Equation 2 accepts a smaller region. ``wall`` (deviation:
        wall-sectors) leaves out photons past the record's walls; ``coverage`` (deviation:
        surface-coverage) replaces the disc's mass by the share of it that is surface and leaves
        out the photons above the surface it measured; with
        ``caster`` (a :class:`~core.rays.RayCaster`; deviation: record-visibility) photons off the
        record's tangent plane that cannot see it are left out.
        """
        radius = a * R_k
        sphere = np.asarray(self.tree.query_ball_point(p_k, radius), dtype=np.int64)
        self.queries += 1
        if len(sphere) == 0:
            return sphere, np.zeros(0), np.zeros(3), 0
        P, N = self.p[sphere], self.n[sphere]
        w = ward_weight(P, N, p_k, n_k, R_k)
        ok = accepted(w, a, P, N, p_k, n_k, R_k)
        cos = N @ n_k
        use = self.is_indirect[sphere] & (cos >= SAME_SURFACE_COS)
        mass = 1.0
        if has_walls(wall):
            # Photons past a wall are another room's: leave them out and normalise the kernel
            # over the part of the disc on this side (Epanechnikov mass within u r: 2u^2 - u^4).
            use &= ~past_walls(wall, P - p_k, n_k)
            if coverage is None:
                u = np.minimum(wall.astype(np.float64) / radius, 1.0)
                mass = max(float(np.mean(2 * u ** 2 - u ** 4)), WALL_MASS_FLOOR)
        if coverage is not None:  # measured by surface_coverage (walls included): the share that is surface
            # The probes see surface up to COVERAGE_LIFT r above the tangent plane; photons higher up (a
            # moulding's step in front of a thin ledge) lie on surface the mass leaves out and would be
            # divided by the ledge's small share alone: measured 6 % of Sponza's texels > 2x Cycles.
            use &= (P - p_k) @ n_k <= COVERAGE_LIFT * radius
            mass = coverage
        if caster is not None:  # photons on the far side of a surface are not this record's
            use[use] = ~caster.hidden_off_plane(p_k, n_k, P[use], N[use])
        used = int(use.sum())
        E_k = np.zeros(3)
        if used:
            d2 = np.sum((P[use] - p_k) ** 2, axis=1)
            kernel = 2.0 / (np.pi * radius * radius) * np.maximum(1.0 - d2 / (radius * radius), 0.0)
            E_k = kernel @ self.power[sphere[use]].astype(np.float64) / mass
        return sphere[ok], w[ok], E_k, used
