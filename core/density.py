"""Photon density estimation for pass 2: R_k (Figure 3) and the Epanechnikov E_k (section 3.2).

:class:`PhotonDensity` holds the kd-tree over an immutable :class:`~core.photons.PhotonMap` and
answers the two queries of record creation, batched over records. It holds nothing computed by
later passes.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from itertools import chain

import numpy as np
from scipy.spatial import cKDTree

from .constants import (COVERAGE_DEPTH, COVERAGE_LIFT, R_K_DISTANCE_FLOOR, R_K_SAME_SIDE_COS, R_OVERSAMPLE,
                        SAME_SURFACE_COS, WALL_MASS_FLOOR)
from .executor import row_chunks, slices
from .photons import PhotonMap
from .record_walls import beyond_wall
from .ward import accepted_from, weight_from
from .vectors import norms


PARALLEL_RECORDS = 64
"""Record creations per :meth:`PhotonDensity.records` call from which the threads share the work."""


class PhotonDensity:
    """kd-trees over the photon map answering the two queries of each record creation."""

    def __init__(self, photons: PhotonMap, workers: int = 1):
        """workers : threads for the kd-tree queries of record placement (pass 2 and hole records run
        those on the calling thread; the executor's chunks query ``tree`` themselves, one thread each)."""
        self.photons = photons
        self.workers = max(1, int(workers))
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
        self._sides = None

    def harmonic_mean_distances(self, p_k: np.ndarray, n_k: np.ndarray, count: int, R_max: float) -> np.ndarray:
        """(B,) float64 R_k for B records (p_k, n_k (B, 3)): Figure 3's harmonic mean; R_max where none fit.

        R_k is the harmonic mean of the distances from p_k to the last hits of the ``count``
        nearest indirect photons. The main tree is asked for R_OVERSAMPLE x ``count`` neighbours
        and the indirect ones on the record's side are kept: a second tree over the indirect
        photons alone would cost ~30 bytes per photon (measured 989 MB peak with it for 4M
        photons through pass 2).
        """
        B = len(p_k)
        R = np.full(B, float(R_max))
        if not self.has_indirect or B == 0:
            return R
        _, idx, valid = self._oversampled_neighbours(p_k, count)
        indirect = valid & self.is_indirect[idx]
        indirect &= np.cumsum(indirect, axis=1) <= count  # the ``count`` nearest indirect ones
        rows, cols = np.nonzero(indirect)
        j = idx[rows, cols]
        to_hit = self.last_hit[j].astype(np.float64) - p_k[rows]
        # Keep photons on the record's side whose last hit lies above its tangent plane.
        ok = (np.einsum("ij,ij->i", self.n[j], n_k[rows]) > R_K_SAME_SIDE_COS) & (
            np.einsum("ij,ij->i", to_hit, n_k[rows]) > 0)
        rows = rows[ok]
        d = np.maximum(norms(to_hit[ok]), R_K_DISTANCE_FLOOR * R_max)
        kept = np.bincount(rows, minlength=B)
        inverse = np.bincount(rows, weights=1.0 / d, minlength=B)
        np.divide(kept, inverse, out=R, where=kept > 0)
        return R

    def photons_per_side(self, face_normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(front, back): (T,) int64 photons that arrived on each triangle's front (the side its face normal
        points to) and on its back. Computed once: the photons hit one scene, whose ``face_normals`` every
        call passes."""
        if self._sides is None:
            triangle = self.photons.triangle.astype(np.int64)
            back = np.empty(len(triangle), bool)
            for s in row_chunks(len(triangle)):
                n_face = np.take(face_normals, triangle[s], axis=0)
                back[s] = np.einsum("ij,ij->i", self.n[s].astype(np.float64), n_face) < 0
            T = len(face_normals)
            self._sides = (np.bincount(triangle[~back], minlength=T), np.bincount(triangle[back], minlength=T))
        return self._sides

    def lit_back_faces(self, face_normals: np.ndarray) -> np.ndarray:
        """(T,) bool: triangles that photons reached on the side their face normal points away from
        (a wall modelled with its normals flipped: light arrives on its back)."""
        return self.photons_per_side(face_normals)[1] > 0

    def back_lit_faces(self, face_normals: np.ndarray) -> np.ndarray:
        """(T,) bool: triangles that more photons reached on their back than on their front: lit from
        behind, so their normals point the wrong way (a photon that slipped through a crack onto the back
        of a front-lit wall does not make it one)."""
        front, back = self.photons_per_side(face_normals)
        return back > front

    def photon_reach(self, p_k: np.ndarray, n_k: np.ndarray, count: int) -> np.ndarray:
        """(B,) float64 distance from each p_k (B, 3) to its ``count``-th nearest indirect photon on
        the surface it faces (n . n_k >= SAME_SURFACE_COS, as E_k counts them); where fewer are among
        the R_OVERSAMPLE x ``count`` nearest photons, the farthest of those (a lower bound)."""
        B = len(p_k)
        if not self.has_indirect or B == 0 or count <= 0:
            return np.zeros(B)
        dist, idx, valid = self._oversampled_neighbours(p_k, count)
        same = np.einsum("bkj,bj->bk", self.n[idx].astype(np.float64), n_k) >= SAME_SURFACE_COS
        counted = np.cumsum(valid & self.is_indirect[idx] & same, axis=1)
        enough = counted[:, -1] >= count
        at = np.argmax(counted >= count, axis=1)
        farthest = np.max(np.where(valid, dist, 0.0), axis=1)
        return np.where(enough, dist[np.arange(B), at], farthest)

    def _oversampled_neighbours(self, p_k: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(distances, photons, valid), each (B, k): the k = R_OVERSAMPLE x ``count`` nearest photons of
        each p_k (B, 3), nearest first; a missing neighbour (fewer photons than k) is photon 0, not valid."""
        B = len(p_k)
        k = min(R_OVERSAMPLE * count, len(self.p))
        dist, idx = self.tree.query(p_k, k=k, workers=self.workers)
        self.queries += B
        dist, idx = np.asarray(dist).reshape(B, k), np.asarray(idx).reshape(B, k)
        valid = idx < len(self.p)
        return dist, np.where(valid, idx, 0), valid

    def record(self, p_k: np.ndarray, n_k: np.ndarray, R_k: float, a: float, wall: np.ndarray | None = None,
               coverage: float | None = None, caster=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """:meth:`records` for one record: (zone (z,) int64, w (z,), E_k (3,), used)."""
        zone = self.records(p_k[None], n_k[None], np.array([R_k], np.float64), a,
                            None if wall is None else np.asarray(wall)[None],
                            None if coverage is None else np.array([coverage]), caster)
        return zone.photons, zone.w, zone.E_k[0], int(zone.used[0])

    def records(self, p_k: np.ndarray, n_k: np.ndarray, R_k: np.ndarray, a: float, wall: np.ndarray | None = None,
                coverage: np.ndarray | None = None, caster=None, own: np.ndarray | None = None) -> "ZoneEstimates":
        """Both photon queries of B record creations, gathering each sphere's photons once.

        p_k, n_k : (B, 3) record positions and unit normals; R_k : (B,) float64; wall : (B, S)
        float32 sector walls or None; coverage : (B,) float64 or None.
        Returns the photons of each S_{a R_k} that record k contributes to (Equation 2) with
        their Ward weights, the Epanechnikov estimates E_k (B, 3) and the number of indirect
        photons each used (:class:`ZoneEstimates`).

        E_k: K(d) = 2 / (pi r^2) * (1 - d^2 / r^2), r = a R_k, integrates to 1 over the
        disc. Photons whose normal disagrees with n_k (n . n_k < SAME_SURFACE_COS: another
        wall of a corner, the far side of a thin wall) are rejected. The selection is by
        distance, not by Ward's weight: the kernel is normalised over the whole disc, and on
        a curved surface Equation 2 accepts a smaller region. ``wall`` (deviation:
        wall-sectors) leaves out photons past the record's walls; ``coverage`` (deviation:
        surface-coverage) replaces the disc's mass by the share of it that is surface and leaves
        out the photons above the surface it measured; with
        ``caster`` (a :class:`~core.rays.RayCaster`; deviation: record-visibility) photons off the
        record's tangent plane that cannot see it are left out. ``own`` (B,) int64 (deviation:
        leave-one-out): the photon each record sits on, left out of its E_k (it stays in its zone).
        """
        B = len(p_k)
        self.queries += B
        if self.workers == 1 or B < PARALLEL_RECORDS:
            return self._records(p_k, n_k, R_k, a, wall, coverage, caster, own, self.workers)
        # Record placement runs on the calling thread, block after block: its numpy work over a
        # block's zone pairs is split between the threads (each record's answer is the same).
        parts = slices(B, -(-B // self.workers))
        part = lambda x, s: None if x is None else x[s]  # noqa: E731
        with ThreadPoolExecutor(len(parts)) as pool:
            return ZoneEstimates.concatenate(list(pool.map(
                lambda s: self._records(p_k[s], n_k[s], R_k[s], a, part(wall, s), part(coverage, s), caster,
                                        part(own, s), 1), parts)))

    def _records(self, p_k, n_k, R_k, a, wall, coverage, caster, own, workers: int) -> "ZoneEstimates":
        """:meth:`records` over one batch of records, its kd-tree query on ``workers`` threads."""
        B = len(p_k)
        radius = a * R_k
        lengths, sphere = ball_pairs(self.tree, p_k, radius, workers)
        rec = np.repeat(np.arange(B), lengths)
        # np.take and np.repeat: fancy row indexing of (N, 3) arrays costs ~3x more (numpy 1.26).
        P, N = np.take(self.p, sphere, axis=0), np.take(self.n, sphere, axis=0).astype(np.float64)
        p_r, n_r, R_r = (np.repeat(x, lengths, axis=0) for x in (p_k, n_k, R_k))
        delta = P - p_r
        d2 = np.einsum("ij,ij->i", delta, delta)
        cos = np.einsum("ij,ij->i", N, n_r)
        w = weight_from(np.sqrt(d2), cos, R_r)
        ok = accepted_from(w, a, np.einsum("ij,ij->i", delta, N + n_r), R_r)
        use = self.is_indirect[sphere] & (cos >= SAME_SURFACE_COS)
        if own is not None:
            # A record placed at a photon is sure to find that photon at its centre, where the kernel
            # peaks: with N photons in the disc it adds ~2/N to E_k (Sponza's Preview records: 1.11 of
            # the path referee's irradiance with it, 0.97 without). The other photons are the unbiased
            # sample of the density around it.
            use &= sphere != np.repeat(own, lengths)
        mass = np.ones(B)
        if wall is not None:
            # Photons past a wall are another room's: leave them out and normalise the kernel
            # over the part of the disc on this side (Epanechnikov mass within u r: 2u^2 - u^4).
            walled = np.isfinite(wall).any(axis=1)
            check = np.flatnonzero(use & walled[rec])
            use[check] = ~beyond_wall(wall[rec[check]], delta[check], n_r[check])
            u = np.minimum(wall.astype(np.float64) / radius[:, None], 1.0)
            mass = np.where(walled, np.maximum(np.mean(2 * u ** 2 - u ** 4, axis=1), WALL_MASS_FLOOR), 1.0)
        if coverage is not None:  # measured by surface_coverage (walls included): the share that is surface
            # The probes see surface up to COVERAGE_LIFT r above the tangent plane; photons higher up (a
            # moulding's step in front of a thin ledge) lie on surface the mass leaves out and would be
            # divided by the ledge's small share alone: measured 6 % of Sponza's texels > 2x Cycles.
            height = np.einsum("ij,ij->i", delta, n_r)
            use &= (height <= COVERAGE_LIFT * radius[rec]) & (height >= -COVERAGE_DEPTH * radius[rec])
            mass = np.asarray(coverage, np.float64)
        if caster is not None:  # photons on the far side of a surface are not this record's
            check = np.flatnonzero(use)
            use[check] = ~caster.hidden_off_plane(p_r[check], n_r[check], P[check], N[check])
        r_use = rec[use]
        r2 = radius[r_use] ** 2
        kernel = 2.0 / (np.pi * r2) * np.maximum(1.0 - d2[use] / r2, 0.0)
        power = np.take(self.power, sphere[use], axis=0).astype(np.float64) * kernel[:, None]
        E_k = np.stack([np.bincount(r_use, weights=power[:, c], minlength=B) for c in range(3)], axis=1)
        return ZoneEstimates(np.bincount(rec[ok], minlength=B), sphere[ok], w[ok], E_k / mass[:, None],
                             np.bincount(r_use, minlength=B))


@dataclass
class ZoneEstimates:
    """What :meth:`PhotonDensity.records` finds for B records.

    lengths : (B,) int64 zone sizes; photons, w : (sum lengths,) int64 / float64, the zone photons
    of record 0, then record 1, ... with their Ward weights (Equation 1).
    E_k : (B, 3) float64 W/m^2; used : (B,) int64 indirect photons in each estimate.
    """

    lengths: np.ndarray
    photons: np.ndarray
    w: np.ndarray
    E_k: np.ndarray
    used: np.ndarray

    @staticmethod
    def concatenate(parts: list["ZoneEstimates"]) -> "ZoneEstimates":
        """The estimates of consecutive batches of records as one."""
        return ZoneEstimates(*(np.concatenate([getattr(part, f) for part in parts]) for f in
                               ("lengths", "photons", "w", "E_k", "used")))


def ball_pairs(tree: cKDTree, points: np.ndarray, radius: np.ndarray, workers: int = 1
               ) -> tuple[np.ndarray, np.ndarray]:
    """Data points within ``radius`` of each query point, in one batched kd-tree query.

    points : (B, 3); radius : (B,) float64. Returns (lengths (B,) int64, idx (sum lengths,) int64):
    the indices near point 0, then those near point 1, ... (unsorted within a point).
    workers : threads for the query; the pairs do not depend on it.
    """
    B = len(points)
    if B == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    lists = tree.query_ball_point(points, radius, return_sorted=False, workers=workers)
    lengths = np.fromiter(map(len, lists), np.int64, B)
    return lengths, np.fromiter(chain.from_iterable(lists), np.int64, int(lengths.sum()))
