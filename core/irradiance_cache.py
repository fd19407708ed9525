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
from .sampling import orthonormal_basis
from .ward import accepted, ward_weight

# Records created before the record kd-tree is rebuilt (neighbour clamping looks
# at the tree plus this many recent records by brute force).
_REBUILD_EVERY = 512
# A candidate block scanned at once when looking for uncovered candidates.
_BLOCK = 4096
WALL_RAYS = 8
"""Azimuth sectors (one tangent-plane ray each) in which a record's zone ends at the nearest wall."""
WALL_LIFT = 0.05
"""Height of the wall rays above the surface, as a fraction of the zone radius."""
WALL_MARGIN = 1e-3
"""Relative margin that keeps the wall bound off exact ties with grid-aligned texel samples."""
FAR_WALL = 1e6
"""A sector ray that hit nothing stands in as a point this many times its neighbour's distance away."""
SECTOR_OFFSET = 0.3819660112501051
"""Sector grid rotation (radians, 1/phi^2): boundaries and rays never align with axis-aligned grids,
where texel samples would sit exactly on a boundary and float noise would pick the sector."""
COVERAGE_RINGS = 4
COVERAGE_ANGLES = 8
"""Probe points of surface_coverage: COVERAGE_RINGS equal-area rings of COVERAGE_ANGLES each."""
COVERAGE_LIFT = 0.05
"""Height above the tangent plane the coverage probes start from, as a fraction of the disc radius."""
COVERAGE_FLOOR = 0.05
"""The least kernel share a record is granted: at most 20x amplification of its photons."""
_TINY_WALL = 1e-30  # the nearest a wall may be: products of two such lengths stay normal float64
R_OVERSAMPLE = 3
"""Neighbours fetched per wanted indirect photon when estimating R_k."""
SAME_SURFACE_COS = 0.7
"""Photons count toward E_k only within ~45 degrees of the record's normal."""


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
            self.wall = np.full((len(self.p), WALL_RAYS), np.inf, np.float32)

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
    """Normalise E_k's kernel by the share of its disc that is surface (:func:`surface_coverage`)."""


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
        self.records: IrradianceCache | None = None  # pass 2's records, set by generate_irradiance_cache
        self.records_lookup = None  # their CacheLookup, built by pass 3 when it needs one
        self.radiance_out = None  # (N, 3) radiance leaving each photon, built by pass 3 for virtual rays

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

    def record(self, p_k: np.ndarray, n_k: np.ndarray, R_k: float, a: float, wall: np.ndarray | None = None,
               coverage: float | None = None, caster=None) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """Both photon queries of one record creation, gathering the sphere's photons once.

        Returns (zone, w, E_k, used): the photons of S_{a R_k} that record k contributes
        to (Equation 2) with their Ward weights, the Epanechnikov estimate E_k (3,) and
        the number of indirect photons it used.

        E_k: K(d) = 2 / (pi r^2) * (1 - d^2 / r^2), r = a R_k, integrates to 1 over the
        disc. Photons whose normal disagrees with n_k (n . n_k < :data:`SAME_SURFACE_COS`:
        another wall of a corner, the far side of a thin wall) are rejected. The
        selection is by distance, not by Ward's weight: the kernel is normalised over
        the whole disc, and on a curved surface Equation 2 accepts a smaller region.
        With ``caster``, photons off the record's tangent plane that cannot see it are left out.
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
        if wall is not None and np.isfinite(wall).any():
            # Photons past a wall are another room's: leave them out and normalise the kernel
            # over the part of the disc on this side (Epanechnikov mass within u r: 2u^2 - u^4).
            m = len(sphere)
            use &= ~beyond_wall(np.broadcast_to(wall, (m, WALL_RAYS)), P - p_k, np.broadcast_to(n_k, (m, 3)))
            if coverage is None:
                u = np.minimum(wall.astype(np.float64) / radius, 1.0)
                mass = max(float(np.mean(2 * u ** 2 - u ** 4)), 1e-3)
        if coverage is not None:  # measured by surface_coverage (walls included): the share that is surface
            mass = coverage
        if caster is not None:  # [record visibility] photons on the far side of a surface are not this one's
            use[use] = ~caster.hidden_off_plane(p_k, n_k, P[use], N[use])
        used = int(use.sum())
        E_k = np.zeros(3)
        if used:
            d2 = np.sum((P[use] - p_k) ** 2, axis=1)
            kernel = 2.0 / (np.pi * radius * radius) * np.maximum(1.0 - d2 / (radius * radius), 0.0)
            E_k = kernel @ self.power[sphere[use]].astype(np.float64) / mass
        return sphere[ok], w[ok], E_k, used


def generate_irradiance_cache(density: PhotonDensity, params: CacheParameters, seed: int,
                              progress=None, caster=None) -> tuple[IrradianceCache, Zones, CacheBuildStats]:
    """Algorithm 1 over the photons themselves; fills the photons' w_sum and E_indirect_sum."""
    photons = density.photons
    # The running sums live in the photons' own float32 fields (section 3.1, zero on arrival): no copy.
    cache, zones, stats = place_records(density, density.p, density.n, photons.w_sum, photons.E_indirect_sum,
                                        params, np.random.default_rng([seed, 2]), candidate_is_photon=True,
                                        progress=progress, caster=caster)
    density.records = cache
    return cache, zones, stats


def place_records(density: PhotonDensity, cand_p: np.ndarray, cand_n: np.ndarray, w_sum: np.ndarray,
                  E_sum: np.ndarray, params: CacheParameters, rng: np.random.Generator,
                  candidate_is_photon: bool, progress=None, existing: IrradianceCache | None = None,
                  caster=None) -> tuple[IrradianceCache, Zones, CacheBuildStats]:
    """The record-placement loop of Algorithm 1 over a generic candidate set.

    cand_p, cand_n : (c, 3) float64 candidate positions and normals.
    w_sum, E_sum : (c,) and (c, 3) float64 running sums, updated in place.
    candidate_is_photon : candidates are the photons themselves (pass 2), so a
        zone's photons are the candidates to update; otherwise (holes) the
        candidates within the zone are found by their own kd-tree.
    existing : records already placed (neighbour clamping also looks at them).
    caster : a :class:`core.rays.RayCaster` over the scene; with it each record finds the walls
        in its tangent plane (:func:`wall_distances`), past which it is not used.
    """
    a = params.a
    threshold = 1.0 / a
    stats = CacheBuildStats()
    rec_p, rec_n, rec_E, rec_R, rec_used, rec_wall = [], [], [], [], [], []
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
            wall = None
            if caster is not None:
                wall = wall_distances(caster, p_k[None], n_k[None], np.array([a * R_k]))[0]
                stats.wall_rays += WALL_RAYS
            # Walls limit where a record is *used* (interpolation, hole coverage). A record at a photon
            # estimates E_k and lends virtual rays from its whole disc: cutting those discs at every
            # corner of a box cost 3 points of Preview error and two thirds of the rays saved on the
            # Cornell box. A hole record may sit where no photon arrives (behind a thin wall); there
            # photons past a wall would leak light in, so its estimate stops at its walls.
            est_wall, est_caster = (None, None) if candidate_is_photon else (wall, caster)
            coverage = None
            if caster is not None and params.kernel_coverage:
                coverage = surface_coverage(caster, p_k, n_k, a * R_k, est_wall)
                stats.wall_rays += COVERAGE_RINGS * COVERAGE_ANGLES
            zone, w, E_k, used = density.record(p_k, n_k, R_k, a, est_wall, coverage, est_caster)
            if candidate_is_photon:
                members, w_members = zone, w
            else:
                members = np.asarray(cand_tree.query_ball_point(p_k, a * R_k), dtype=np.int64)
                stats.kd_queries += 1
                P, N = cand_p[members], cand_n[members]
                w_members = ward_weight(P, N, p_k, n_k, R_k)
                ok = accepted(w_members, a, P, N, p_k, n_k, R_k)
                if wall is not None:
                    m = len(members)
                    ok &= ~beyond_wall(np.broadcast_to(wall, (m, WALL_RAYS)), P - p_k, np.broadcast_to(n_k, (m, 3)))
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
            rec_wall.append(wall if wall is not None else np.full(WALL_RAYS, np.inf, np.float32))
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
        refined=np.zeros(K, bool), wall=np.array(rec_wall, np.float32).reshape(K, WALL_RAYS))
    zones = Zones(zone_photons)
    return cache, zones, stats


def _ray_angle(i) -> np.ndarray:
    """Tangent-plane angle of wall ray ``i`` (0..WALL_RAYS-1), from t1 of the record's frame."""
    return SECTOR_OFFSET + 2 * np.pi * (np.asarray(i) + 0.5) / WALL_RAYS


def wall_distances(caster, p_k: np.ndarray, n_k: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """(K, WALL_RAYS) float32 distance to the nearest wall per sector of each record's tangent plane.

    A zone of influence is a sphere: where a wall stands on the surface (a 1 mm
    partition on a floor, a box resting on it), the sphere reaches the floor on
    the wall's far side, same plane, same normal, and Ward's weights carry light
    through. One ray per sector, along the tangent plane at the sector's centre
    angle and lifted by :data:`WALL_LIFT` of the reach, finds such walls up to
    ``reach`` (K,); texels and photons past a sector's wall are not the record's.
    """
    K = len(p_k)
    phi = _ray_angle(np.arange(WALL_RAYS))
    t1, t2 = orthonormal_basis(n_k)
    d = (np.cos(phi)[None, :, None] * t1[:, None] + np.sin(phi)[None, :, None] * t2[:, None]).reshape(-1, 3)
    origin = np.repeat(p_k + (WALL_LIFT * reach)[:, None] * n_k, WALL_RAYS, axis=0)
    t_max = np.repeat(reach, WALL_RAYS)
    t = caster.intersect(origin, d, t_max=t_max).t
    # A lifted origin lying on another surface (a record where a railing bar meets the rail it
    # holds) hits that surface at t = 0 in every direction: all walls at 0 make the kernel mass
    # in PhotonDensity.record hit its 1e-3 floor while beyond_wall, whose segments are then
    # points, rejects no photon, so E_k came out 1000x too high. Look again from just past it.
    start = np.flatnonzero(t <= caster.epsilon)
    if len(start):
        step = caster.epsilon
        t[start] = step + caster.intersect(origin[start] + step * d[start], d[start], t_max=t_max[start] - step).t
    return t.reshape(K, WALL_RAYS).astype(np.float32)


def surface_coverage(caster, p_k: np.ndarray, n_k: np.ndarray, radius: float, wall: np.ndarray | None) -> float:
    """Share of the Epanechnikov kernel's mass over the disc of ``radius`` that lies on the record's surface.

    Density estimation divides by the whole disc, but photons land only on surface: on a 4 cm
    railing bar, a column's flank or a floor's open edge most of the disc is empty and E_k came
    out several times too low (the occluded building's railings: 0.43 against Cycles' 2.89,
    E/pi). Probe points over the disc (equal-area rings, :data:`COVERAGE_RINGS` x
    :data:`COVERAGE_ANGLES`) each cast a short ray down onto the tangent plane from just above
    it; a point counts if it finds surface facing like n_k there and is not past a wall.
    Returns a value in [COVERAGE_FLOOR, 1].
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
    if wall is not None and np.isfinite(wall).any():
        present &= ~beyond_wall(np.broadcast_to(wall, (m, WALL_RAYS)), offset, np.broadcast_to(n_k, (m, 3)))
    return float(max(np.sum(_COVERAGE_KERNEL * present) / np.sum(_COVERAGE_KERNEL), COVERAGE_FLOOR))


def _coverage_pattern() -> tuple[np.ndarray, np.ndarray]:
    """(u = d / r, angle) of the coverage probes: equal-area rings, every other ring turned half a step."""
    rings = np.sqrt((np.arange(COVERAGE_RINGS) + 0.5) / COVERAGE_RINGS)
    steps = np.arange(COVERAGE_ANGLES) + 0.5 * (np.arange(COVERAGE_RINGS)[:, None] % 2)
    angles = SECTOR_OFFSET + 2 * np.pi * steps / COVERAGE_ANGLES
    return np.broadcast_to(rings[:, None], angles.shape).ravel(), angles.ravel()


_COVERAGE_U, _COVERAGE_PHI = _coverage_pattern()
_COVERAGE_KERNEL = 1.0 - _COVERAGE_U ** 2  # Epanechnikov weight of each probe


def wall_clearance(wall: np.ndarray) -> np.ndarray:
    """(K,) radius around each record inside which no point is past any of its walls (inf: no wall).

    The star polygon's edge between rays at distances r <= s, 2 pi / S apart, lies at least
    r sin(2 pi / S) from the record when s >= r / (2 cos(2 pi / S)), always true for S >= 6;
    so the disc of radius min(wall) (1 - WALL_MARGIN) sin(2 pi / S) is inside the polygon
    and :func:`beyond_wall` need not be asked about points within it (most pairs).
    """
    nearest = np.min(np.asarray(wall, np.float64), axis=1) if wall.shape[1] else np.full(len(wall), np.inf)
    return nearest * (1.0 - WALL_MARGIN) * np.sin(2 * np.pi / WALL_RAYS)


def beyond_wall(wall: np.ndarray, delta: np.ndarray, n_k: np.ndarray) -> np.ndarray:
    """(m,) bool: offsets ``delta`` from records (normals n_k, sector walls ``wall`` (m, S)) lie past a wall.

    The record sees, in its tangent plane, the star polygon through its sector rays' hits:
    a point between two neighbouring rays is past the wall if it lies beyond the segment
    joining their hits (a ray that hit nothing stands in with a far point). The segment
    follows a straight wall whatever its angle to the rays, so directions parallel to a
    wall keep their reach, and nothing behind a wall slips between two rays.
    """
    t1, t2 = orthonormal_basis(n_k)
    x = np.einsum("ij,ij->i", delta, t1)
    y = np.einsum("ij,ij->i", delta, t2)
    turn = np.mod((np.arctan2(y, x) - SECTOR_OFFSET) / (2 * np.pi), 1.0) * WALL_RAYS - 0.5
    i = np.floor(turn).astype(np.int64) % WALL_RAYS  # the ray just before the point's direction
    j = (i + 1) % WALL_RAYS
    rows = np.arange(len(delta))
    t_i, t_j = wall[rows, i].astype(np.float64), wall[rows, j].astype(np.float64)
    finite = np.isfinite(t_i) | np.isfinite(t_j)
    far = FAR_WALL * np.where(np.isfinite(t_i), t_i, np.where(np.isfinite(t_j), t_j, 1.0))
    # A wall at distance 0 would make its segment a point through the record, on whose line
    # every point lies: nothing would be past it while PhotonDensity.record's kernel mass for
    # it is ~0 (E_k came out 1000x too high). A tiny positive distance keeps the polygon a polygon.
    t_i = np.maximum(np.where(np.isfinite(t_i), t_i, far) * (1.0 - WALL_MARGIN), _TINY_WALL)
    t_j = np.maximum(np.where(np.isfinite(t_j), t_j, far) * (1.0 - WALL_MARGIN), _TINY_WALL)
    a_i, a_j = _ray_angle(i), _ray_angle(j)
    hx_i, hy_i = t_i * np.cos(a_i), t_i * np.sin(a_i)
    hx_j, hy_j = t_j * np.cos(a_j), t_j * np.sin(a_j)
    ex, ey = hx_j - hx_i, hy_j - hy_i
    # The origin and the point on opposite sides of the segment's line: the point is past the wall.
    side_point = ex * (y - hy_i) - ey * (x - hx_i)
    side_origin = ex * (0.0 - hy_i) - ey * (0.0 - hx_i)
    return finite & (side_point * side_origin < 0)


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
