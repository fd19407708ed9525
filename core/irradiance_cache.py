"""Pass 2: the irradiance cache generated from the photon map (paper section 3.2, Algorithm 1).

Algorithm 1, as implemented::

    for each candidate (photon) c in a seeded random order with w_sum[c] < 1/a:
        R_k  <- harmonic mean of |p_lh - p_k| over the n nearest indirect photons (Figure 3),
                kept in [R_min, R_max] and neighbour-clamped [KBPZ06]
        zone <- candidates and photons within a R_k whose Ward weight passes Equation 2
        E_k  <- Epanechnikov density estimate of the indirect photons of the zone, bandwidth a R_k
        create record k = (p_k, n_k, E_k, R_k)
        for each candidate c' in the zone: w_sum[c'] += w_k(c'); E_sum[c'] += w_k(c') E_k

**Threshold.** The paper writes both ``w_sum < 1/a`` (Algorithm 1) and
``w_sum < a`` (text). We use ``w_sum < 1/a``: with Equation 2 a record only
contributes where its weight exceeds 1/a, so ``w_sum >= 1/a`` holds exactly
when at least one record covers the photon; for a < 1 the two readings then
select the same photons (every accepted contribution alone exceeds 1/a > a),
and ``1/a`` also stays meaningful for a >= 1.

**Order.** Photons are walked in a seeded random permutation rather than
storage order (which is grouped by bounce and light) so records spread evenly.

**Neighbour clamping.** A new record's R_k is clamped against the records
already near it (R_k <= R_j + |p_k - p_j|). After the walk, one min-plus pass
makes the whole set consistent (one pass suffices: the result is 1-Lipschitz).
Photon weights are not recomputed after that final pass; texels it leaves
uncovered become hole records (section 3.4), which the light-map stage fills.

Candidates are generic (positions + normals + a w_sum array): the photons in
pass 2, and texel points left in holes at light-map time.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from .photons import PhotonMap
from .ward import accepted, ward_weight

# Records created before the record kd-tree is rebuilt (neighbour clamping looks
# at the tree plus this many recent records by brute force).
_REBUILD_EVERY = 512
# A candidate block scanned at once when looking for uncovered candidates.
_BLOCK = 4096
R_OVERSAMPLE = 3
"""Neighbours fetched per wanted indirect photon when estimating R_k."""
SAME_SURFACE_COS = 0.7
"""Photons count toward E_k only within ~45 degrees of the record's normal."""


@dataclass
class IrradianceCache:
    """Irradiance records, struct of arrays (K records; 8*(3+3+3+1+9+9) + 4 + 1 + 1 = 230 bytes each).

    p, n : (K, 3) float64 scene-local position and unit normal of each record.
    E : (K, 3) float64 indirect irradiance E_k, W/m^2.
    R : (K,) float64 harmonic mean distance R_k (zone of influence radius a R_k).
    grad_r, grad_t : (K, 3, 3) float64 rotational / translational gradients [record, channel, xyz].
    photons_used : (K,) int32 indirect photons in the density estimate of E_k.
    hole : (K,) bool records created for light-map holes (section 3.4) rather than at photons.
    refined : (K,) bool records whose E_k came from final gathering (pass 3).
    """

    p: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    n: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    E: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    R: np.ndarray = field(default_factory=lambda: np.zeros(0))
    grad_r: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    grad_t: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    photons_used: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    hole: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    refined: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    def __len__(self) -> int:
        return len(self.p)

    def extend(self, other: "IrradianceCache") -> "IrradianceCache":
        return IrradianceCache(*(np.concatenate([getattr(self, f), getattr(other, f)])
                                 for f in self.__dataclass_fields__))

    def take(self, index) -> "IrradianceCache":
        return IrradianceCache(*(getattr(self, f)[index] for f in self.__dataclass_fields__))


@dataclass(frozen=True)
class CacheParameters:
    """Parameters of Algorithm 1.

    a : Ward's accuracy (zone radius a R_k, Equation 2 threshold 1/a).
    r_nearest : photons in the harmonic-mean estimate of R_k.
    R_min, R_max : bounds on R_k in scene units (tied to texel and scene size).
    """

    a: float
    r_nearest: int
    R_min: float
    R_max: float


@dataclass
class Zones:
    """Photons in each record's zone of influence: ``parts[k]`` (int32 indices) for record k.

    Kept as one array per record rather than one concatenated array: the copy would
    double the zones' memory at the moment pass 2 peaks (66 MB for 4M photons).
    """

    parts: list

    def batch(self, s: slice) -> tuple[np.ndarray, np.ndarray]:
        """(lengths (b,), photons (sum,) int64) of records s.start..s.stop-1, in record order."""
        chunk = self.parts[s]
        lengths = np.array([len(z) for z in chunk], np.int64)
        photons = np.concatenate(chunk).astype(np.int64) if chunk else np.zeros(0, np.int64)
        return lengths, photons


@dataclass
class CacheBuildStats:
    records: int = 0
    kd_queries: int = 0
    candidates_visited: int = 0


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

        The main tree is asked for :data:`R_OVERSAMPLE` x ``count`` neighbours and the
        indirect ones on the record's side are kept: a second tree over the indirect
        photons alone would cost ~30 bytes per photon (measured 989 MB peak with it for
        4M photons through pass 2).
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
        ok = (self.n[idx] @ n_k > 0.5) & (to_hit @ n_k > 0)
        if not ok.any():
            return R_max
        d = np.linalg.norm(to_hit[ok], axis=1)
        d = np.maximum(d, 1e-12 * R_max)
        return float(ok.sum() / np.sum(1.0 / d))

    def record(self, p_k: np.ndarray, n_k: np.ndarray, R_k: float, a: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """Both photon queries of one record creation, gathering the sphere's photons once.

        Returns (zone, w, E_k, used): the photons of S_{a R_k} that record k contributes
        to (Equation 2) with their Ward weights, the Epanechnikov estimate E_k (3,) and
        the number of indirect photons it used.

        E_k: K(d) = 2 / (pi r^2) * (1 - d^2 / r^2), r = a R_k, integrates to 1 over the
        disc. Photons whose normal disagrees with n_k (n . n_k < :data:`SAME_SURFACE_COS`:
        another wall of a corner, the far side of a thin wall) are rejected. The
        selection is by distance, not by Ward's weight: the kernel is normalised over
        the whole disc, and on a curved surface Equation 2 accepts a smaller region.
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
        used = int(use.sum())
        E_k = np.zeros(3)
        if used:
            d2 = np.sum((P[use] - p_k) ** 2, axis=1)
            kernel = 2.0 / (np.pi * radius * radius) * np.maximum(1.0 - d2 / (radius * radius), 0.0)
            E_k = kernel @ self.power[sphere[use]].astype(np.float64)
        return sphere[ok], w[ok], E_k, used


def generate_irradiance_cache(density: PhotonDensity, params: CacheParameters, seed: int,
                              progress=None) -> tuple[IrradianceCache, Zones, CacheBuildStats]:
    """Algorithm 1 over the photons themselves; fills the photons' w_sum and E_indirect_sum."""
    photons = density.photons
    # The running sums live in the photons' own float32 fields (section 3.1, zero on arrival): no copy.
    return place_records(density, density.p, density.n, photons.w_sum, photons.E_indirect_sum, params,
                         np.random.default_rng([seed, 2]), candidate_is_photon=True, progress=progress)


def place_records(density: PhotonDensity, cand_p: np.ndarray, cand_n: np.ndarray, w_sum: np.ndarray,
                  E_sum: np.ndarray, params: CacheParameters, rng: np.random.Generator,
                  candidate_is_photon: bool, progress=None, existing: IrradianceCache | None = None
                  ) -> tuple[IrradianceCache, Zones, CacheBuildStats]:
    """The record-placement loop of Algorithm 1 over a generic candidate set.

    cand_p, cand_n : (c, 3) float64 candidate positions and normals.
    w_sum, E_sum : (c,) and (c, 3) float64 running sums, updated in place.
    candidate_is_photon : candidates are the photons themselves (pass 2), so a
        zone's photons are the candidates to update; otherwise (holes) the
        candidates within the zone are found by their own kd-tree.
    existing : records already placed (neighbour clamping also looks at them).
    """
    a = params.a
    threshold = 1.0 / a
    stats = CacheBuildStats()
    rec_p, rec_n, rec_E, rec_R, rec_used = [], [], [], [], []
    zone_photons = []
    clamp = _NeighbourClamp(existing)
    cand_tree = None if candidate_is_photon else cKDTree(cand_p)
    order = rng.permutation(len(cand_p))
    for b0 in range(0, len(order), _BLOCK):
        block = order[b0:b0 + _BLOCK]
        for c in block[w_sum[block] < threshold]:
            stats.candidates_visited += 1
            if w_sum[c] >= threshold:  # covered by a record created earlier in this block
                continue
            p_k, n_k = cand_p[c], cand_n[c]
            R_k = density.harmonic_mean_distance(p_k, n_k, params.r_nearest, params.R_max)
            R_k = min(max(R_k, params.R_min), params.R_max)
            R_k = clamp.clamp(p_k, R_k)
            zone, w, E_k, used = density.record(p_k, n_k, R_k, a)
            if candidate_is_photon:
                members, w_members = zone, w
            else:
                members = np.asarray(cand_tree.query_ball_point(p_k, a * R_k), dtype=np.int64)
                stats.kd_queries += 1
                P, N = cand_p[members], cand_n[members]
                w_members = ward_weight(P, N, p_k, n_k, R_k)
                ok = accepted(w_members, a, P, N, p_k, n_k, R_k)
                members, w_members = members[ok], w_members[ok]
            w_sum[members] += w_members
            E_sum[members] += w_members[:, None] * E_k
            # The candidate is covered by its own record even if Equation 2 rounding dropped it.
            if w_sum[c] < threshold:
                E_sum[c] += (threshold - w_sum[c]) * E_k
                w_sum[c] = threshold
            rec_p.append(p_k)
            rec_n.append(n_k)
            rec_E.append(E_k)
            rec_R.append(R_k)
            rec_used.append(used)
            zone_photons.append(zone.astype(np.int32))
            clamp.add(p_k, R_k)
        if progress is not None:
            progress.update(min(1.0, (b0 + len(block)) / max(len(order), 1)))
    K = len(rec_p)
    stats.records = K
    stats.kd_queries += density.queries
    cache = IrradianceCache(
        p=np.array(rec_p, np.float64).reshape(K, 3), n=np.array(rec_n, np.float64).reshape(K, 3),
        E=np.array(rec_E, np.float64).reshape(K, 3), R=np.array(rec_R, np.float64),
        grad_r=np.zeros((K, 3, 3)), grad_t=np.zeros((K, 3, 3)),
        photons_used=np.array(rec_used, np.int32), hole=np.full(K, not candidate_is_photon),
        refined=np.zeros(K, bool))
    zones = Zones(zone_photons)
    return cache, zones, stats


def neighbour_clamp(p: np.ndarray, R: np.ndarray) -> np.ndarray:
    """One min-plus pass: R_k <- min_j (R_j + |p_k - p_j|) over neighbours within R_k ([KBPZ06]).

    The result satisfies R_k <= R_j + |p_k - p_j| for every pair, so a single pass is final.
    """
    if len(p) < 2:
        return R.copy()
    tree = cKDTree(p)
    out = R.copy()
    pairs = tree.query_pairs(float(R.max()), output_type="ndarray")
    if len(pairs) == 0:
        return out
    i, j = pairs[:, 0], pairs[:, 1]
    d = np.linalg.norm(p[i] - p[j], axis=1)
    np.minimum.at(out, i, R[j] + d)
    np.minimum.at(out, j, R[i] + d)
    return out


class _NeighbourClamp:
    """R_k <= R_j + |p_k - p_j| against records placed so far (kd-tree + recent list)."""

    def __init__(self, existing: IrradianceCache | None):
        self.tree_p = existing.p.copy() if existing is not None and len(existing) else np.zeros((0, 3))
        self.tree_R = existing.R.copy() if existing is not None and len(existing) else np.zeros(0)
        self.tree = cKDTree(self.tree_p) if len(self.tree_p) else None
        self.recent_p, self.recent_R = [], []

    def clamp(self, p_k: np.ndarray, R_k: float) -> float:
        if self.tree is not None:
            idx = self.tree.query_ball_point(p_k, R_k)
            if idx:
                d = np.linalg.norm(self.tree_p[idx] - p_k, axis=1)
                R_k = min(R_k, float(np.min(self.tree_R[idx] + d)))
        if self.recent_p:
            d = np.linalg.norm(np.asarray(self.recent_p) - p_k, axis=1)
            R_k = min(R_k, float(np.min(np.asarray(self.recent_R) + d)))
        return R_k

    def add(self, p_k: np.ndarray, R_k: float):
        self.recent_p.append(p_k)
        self.recent_R.append(R_k)
        if len(self.recent_p) >= _REBUILD_EVERY:
            self.tree_p = np.concatenate([self.tree_p, np.asarray(self.recent_p)])
            self.tree_R = np.concatenate([self.tree_R, np.asarray(self.recent_R)])
            self.tree = cKDTree(self.tree_p)
            self.recent_p, self.recent_R = [], []
