"""Pass 2: the irradiance cache generated from the photon map (paper section 3.2, Algorithm 1).

Two entry points run the same record-placement loop: :func:`cache_from_photons` (pass 2, the
candidates are the photons) and :func:`cache_for_holes` (section 3.4, the candidates are texel
samples no record covers; see :mod:`core.hole_records`). Density estimation lives in
:mod:`core.density`, record walls in :mod:`core.record_walls`, surface coverage in
:mod:`core.coverage`.

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

from .constants import COVERAGE_ANGLES, COVERAGE_RINGS, STREAM_RECORD_ORDER, WALL_RAYS
from .coverage import surface_coverage
from .density import PhotonDensity
from .photons import PhotonLighting
from .record_walls import open_walls, past_walls, wall_distances
from .ward import accepted, ward_weight

# Records created before the record kd-tree is rebuilt (neighbour clamping looks
# at the tree plus this many recent records by brute force).
_REBUILD_EVERY = 512
# A candidate block scanned at once when looking for uncovered candidates.
_BLOCK = 4096


@dataclass
class IrradianceCache:
    """Irradiance records, struct of arrays (K records; 8*(3+3+3+1+9+9) + 4 + 1 + 1 + 4*8 = 262 bytes each).

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
    wall: np.ndarray | None = None
    """(K, WALL_RAYS) float32 distance to the nearest wall per azimuth sector of the record's
    tangent plane (inf: none within reach); None = no walls known (every sector open)."""

    def __post_init__(self):
        if self.wall is None:
            self.wall = open_walls(len(self.p))

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
    kernel_coverage : see the field; on for Preview, whose light maps are pass 2's E_k.
    """

    a: float
    r_nearest: int
    R_min: float
    R_max: float
    kernel_coverage: bool = False
    """Normalise E_k's kernel by the share of its disc that is surface (deviation: surface-coverage)."""
    wall_sectors: bool = True
    """Records find their walls (deviation: wall-sectors); False leaves every sector open."""
    neighbour_clamp: bool = True
    """R_k <= R_j + |p_k - p_j| between records ([KBPZ06]; deviation: neighbour-clamp)."""
    record_visibility: bool = True
    """Records and hole records' photons off a point's tangent plane count only if they see it
    (deviation: record-visibility)."""


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
    wall_rays: int = 0


# --------------------------------------------------------------------------- entry points
def cache_from_photons(density: PhotonDensity, params: CacheParameters, seed: int, progress=None, caster=None
                       ) -> tuple[IrradianceCache, Zones, PhotonLighting, CacheBuildStats]:
    """Pass 2: Algorithm 1 over the photons themselves, then one final neighbour clamp.

    Returns the records, their zones (photons each record covers, for pass 3), the photons'
    section 3.1 sums (w_sum, E_indirect_sum: a new value, the photon map stays untouched)
    and counters.
    """
    lighting = PhotonLighting.zeros(len(density.p))
    cache, zones, stats = place_records(density, density.p, density.n, lighting.w_sum, lighting.E_indirect_sum,
                                        params, np.random.default_rng([seed, STREAM_RECORD_ORDER]),
                                        candidate_is_photon=True, progress=progress, caster=caster)
    if params.neighbour_clamp:  # deviation: neighbour-clamp, docs/DEVIATIONS.md
        cache.R = neighbour_clamp(cache.p, cache.R)
    return cache, zones, lighting, stats


def cache_for_holes(density: PhotonDensity, cand_p: np.ndarray, cand_n: np.ndarray, params: CacheParameters,
                    rng: np.random.Generator, existing: IrradianceCache, caster=None
                    ) -> tuple[IrradianceCache, Zones, CacheBuildStats]:
    """Section 3.4: Algorithm 1 over texel samples (c, 3) no record covers; records flagged ``hole``."""
    return place_records(density, cand_p, cand_n, np.zeros(len(cand_p)), np.zeros((len(cand_p), 3)), params, rng,
                         candidate_is_photon=False, existing=existing, caster=caster)


# --------------------------------------------------------------------------- Algorithm 1
def place_records(density: PhotonDensity, cand_p: np.ndarray, cand_n: np.ndarray, w_sum: np.ndarray,
                  E_sum: np.ndarray, params: CacheParameters, rng: np.random.Generator,
                  candidate_is_photon: bool, progress=None, existing: IrradianceCache | None = None,
                  caster=None) -> tuple[IrradianceCache, Zones, CacheBuildStats]:
    """The record-placement loop of Algorithm 1 over a generic candidate set.

    cand_p, cand_n : (c, 3) float64 candidate positions and normals.
    w_sum, E_sum : (c,) and (c, 3) running sums, updated in place.
    candidate_is_photon : candidates are the photons themselves (pass 2), so a
        zone's photons are the candidates to update; otherwise (holes) the
        candidates within the zone are found by their own kd-tree.
    existing : records already placed (neighbour clamping also looks at them).
    caster : a :class:`core.rays.RayCaster` over the scene; with it each record finds the walls
        in its tangent plane (:func:`~core.record_walls.wall_distances`), past which it is not used.
    """
    threshold = 1.0 / params.a
    stats = CacheBuildStats()
    records = _Records()
    clamp = _NeighbourClamp(existing, params.neighbour_clamp)
    cand_tree = None if candidate_is_photon else cKDTree(cand_p)
    order = rng.permutation(len(cand_p))
    for b0 in range(0, len(order), _BLOCK):
        block = order[b0:b0 + _BLOCK]
        for c in block[w_sum[block] < threshold]:
            stats.candidates_visited += 1
            if w_sum[c] >= threshold:  # covered by a record created earlier in this block
                continue
            p_k, n_k = cand_p[c], cand_n[c]
            R_k, wall, E_k, used, zone, members, w_members = _create_record(
                density, p_k, n_k, params, clamp, caster, cand_tree, cand_p, cand_n, candidate_is_photon, stats)
            w_sum[members] += w_members
            E_sum[members] += w_members[:, None] * E_k
            # The candidate is covered by its own record even if Equation 2 rounding dropped it.
            if w_sum[c] < threshold:
                E_sum[c] += (threshold - w_sum[c]) * E_k
                w_sum[c] = threshold
            records.add(p_k, n_k, E_k, R_k, used, wall, zone)
            clamp.add(p_k, R_k)
        if progress is not None:
            progress.update(min(1.0, (b0 + len(block)) / max(len(order), 1)))
    stats.records = len(records)
    stats.kd_queries += density.queries
    return records.cache(hole=not candidate_is_photon), Zones(records.zones), stats


def _create_record(density, p_k, n_k, params: CacheParameters, clamp, caster, cand_tree, cand_p, cand_n,
                   candidate_is_photon: bool, stats: CacheBuildStats):
    """One record of Algorithm 1 at candidate (p_k, n_k): R_k, walls, E_k and the candidates it covers.

    Returns (R_k, wall (S,) or None, E_k (3,), photons used, zone photons, covered candidates, their w).
    """
    a = params.a
    R_k = density.harmonic_mean_distance(p_k, n_k, params.r_nearest, params.R_max)
    R_k = min(max(R_k, params.R_min), params.R_max)
    R_k = clamp.clamp(p_k, R_k)
    wall = None
    if caster is not None and params.wall_sectors:  # deviation: wall-sectors, docs/DEVIATIONS.md
        wall = wall_distances(caster, p_k[None], n_k[None], np.array([a * R_k]))[0]
        stats.wall_rays += WALL_RAYS
    # Walls limit where a record is *used* (interpolation, hole coverage). A record at a photon
    # estimates E_k and lends virtual rays from its whole disc: cutting those discs at every corner
    # of a room removes most of the photons a corner record has, which made Preview noisier and
    # pass 3 cast more real rays. A hole record may sit where no photon arrives (behind a thin
    # wall); there photons past a wall would leak light in, so its estimate stops at its walls, and
    # photons off its tangent plane that cannot see it (a closed box's inside) are not its own.
    est_wall = None if candidate_is_photon else wall
    est_caster = caster if not candidate_is_photon and params.record_visibility else None  # deviation: record-visibility
    coverage = None
    if caster is not None and params.kernel_coverage:  # deviation: surface-coverage, docs/DEVIATIONS.md
        coverage = surface_coverage(caster, p_k, n_k, a * R_k, est_wall)
        stats.wall_rays += COVERAGE_RINGS * COVERAGE_ANGLES
    zone, w, E_k, used = density.record(p_k, n_k, R_k, a, est_wall, coverage, est_caster)
    if candidate_is_photon:
        return R_k, wall, E_k, used, zone, zone, w
    members = np.asarray(cand_tree.query_ball_point(p_k, a * R_k), dtype=np.int64)
    stats.kd_queries += 1
    P, N = cand_p[members], cand_n[members]
    w_members = ward_weight(P, N, p_k, n_k, R_k)
    ok = accepted(w_members, a, P, N, p_k, n_k, R_k)
    if wall is not None:
        ok &= ~past_walls(wall, P - p_k, n_k)
    return R_k, wall, E_k, used, zone, members[ok], w_members[ok]


class _Records:
    """Records as they are placed, assembled into an :class:`IrradianceCache` at the end."""

    def __init__(self):
        self.p, self.n, self.E, self.R, self.used, self.wall, self.zones = [], [], [], [], [], [], []

    def __len__(self) -> int:
        return len(self.p)

    def add(self, p_k, n_k, E_k, R_k, used, wall, zone):
        self.p.append(p_k)
        self.n.append(n_k)
        self.E.append(E_k)
        self.R.append(R_k)
        self.used.append(used)
        self.wall.append(wall if wall is not None else np.full(WALL_RAYS, np.inf, np.float32))
        self.zones.append(zone.astype(np.int32))

    def cache(self, hole: bool) -> IrradianceCache:
        K = len(self.p)
        return IrradianceCache(
            p=np.array(self.p, np.float64).reshape(K, 3), n=np.array(self.n, np.float64).reshape(K, 3),
            E=np.array(self.E, np.float64).reshape(K, 3), R=np.array(self.R, np.float64),
            grad_r=np.zeros((K, 3, 3)), grad_t=np.zeros((K, 3, 3)),
            photons_used=np.array(self.used, np.int32), hole=np.full(K, hole),
            refined=np.zeros(K, bool), wall=np.array(self.wall, np.float32).reshape(K, WALL_RAYS))


# --------------------------------------------------------------------------- neighbour clamping [KBPZ06]
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

    def __init__(self, existing: IrradianceCache | None, enabled: bool = True):
        self.enabled = enabled
        self.tree_p = existing.p.copy() if existing is not None and len(existing) else np.zeros((0, 3))
        self.tree_R = existing.R.copy() if existing is not None and len(existing) else np.zeros(0)
        self.tree = cKDTree(self.tree_p) if len(self.tree_p) and enabled else None
        self.recent_p, self.recent_R = [], []

    def clamp(self, p_k: np.ndarray, R_k: float) -> float:
        if not self.enabled:
            return R_k
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
        if not self.enabled:
            return
        self.recent_p.append(p_k)
        self.recent_R.append(R_k)
        if len(self.recent_p) >= _REBUILD_EVERY:
            self.tree_p = np.concatenate([self.tree_p, np.asarray(self.recent_p)])
            self.tree_R = np.concatenate([self.tree_R, np.asarray(self.recent_R)])
            self.tree = cKDTree(self.tree_p)
            self.recent_p, self.recent_R = [], []
