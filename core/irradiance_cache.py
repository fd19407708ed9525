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

**Blocks.** The loop runs over blocks of up to _BLOCK uncovered candidates (fewer where zones
hold many photons, so a block's zone pairs stay near _ZONE_PAIRS), taken in the seeded
order, each step batched over the block (one kd-tree query for all R_k, one ray cast for all
walls, one density estimate, one w_sum update). Within a block, candidate i gets a record
unless an earlier picked candidate's record accepts it (Equation 2 with that record's R_k
clamped against the records of earlier blocks): the sequential walk's outcome, except that
the sequential walk would also clamp R_j against the block's earlier records and consult
walls, both of which only shrink zones. Those are applied after the pick (R_k clamped in
block order, walls cast); candidates they leave uncovered are walked again as the next
block, so no candidate ends with w_sum < 1/a and no record's zone covers the centre of a
record placed after it, as in the sequential walk. The records can differ from it where a
clamped or walled zone would have let a later block candidate cover others first
(tests/test_block_walk.py holds the counts to the sequential walk's).

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
That pass shrinks zones Algorithm 1 had counted on: the photons it leaves outside
every zone (35 % of them on the cathedral, 39 % on Sponza at 16 texels/m) start
records again, Algorithm 1 over them clamped against the rest, then the pass again
(deviation: clamp-recovery, CLAMP_RECOVERY_ROUNDS rounds). Texels still uncovered
become hole records (section 3.4), which the light-map stage fills.

Candidates are generic (positions + normals + a w_sum array): the photons in
pass 2, and texel points left in holes at light-map time.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from . import native_kernels
from .constants import CLAMP_RECOVERY_ROUNDS, COVERAGE_ANGLES, COVERAGE_RINGS, STREAM_RECORD_ORDER, WALL_RAYS
from .coverage import surface_coverages
from .density import PhotonDensity, ZoneEstimates, ball_pairs
from .executor import slices
from .photons import PhotonLighting
from .record_walls import beyond_wall, open_walls, wall_distances
from .ward import accepted, ward_weight
from .vectors import norms

# Uncovered candidates handled together (one batched kd-tree query, ray cast and density estimate).
_BLOCK = 2048
# Zone photons (record, photon pairs) a block aims at: ~400 bytes each in flight, so ~100 MB
# (4M photons in a small box hold ~10k per zone: a full block would need GBs).
_ZONE_PAIRS = 262_144
CLAMP_CHUNK = 1024
"""Records whose neighbour-clamp balls are queried together (their pairs are held as Python lists)."""
CLAMP_NEIGHBOURS = 16
"""Nearest records asked first by a neighbour clamp (:func:`_clamped`): 16 settle most records."""


@dataclass
class IrradianceCache:
    """Irradiance records, struct of arrays (K records; 8*(3+3+3+1+9+9) + 4 + 1 + 1 + 4*8 = 262 bytes each,
    168 more with the gathered sky).

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
    E_sky: np.ndarray | None = None
    """(K, 3) float64 the world's irradiance gathered at each record (deviation: sky-gathering), W/m^2;
    None when the sky is not gathered."""
    grad_r_sky: np.ndarray | None = None
    """(K, 3, 3) its rotational gradient, as grad_r; None with E_sky."""
    grad_t_sky: np.ndarray | None = None
    """(K, 3, 3) its translational gradient, as grad_t; None with E_sky."""

    def __post_init__(self):
        if self.wall is None:
            self.wall = open_walls(len(self.p))

    def __len__(self) -> int:
        return len(self.p)

    @property
    def has_sky(self) -> bool:
        return self.E_sky is not None

    def extend(self, other: "IrradianceCache") -> "IrradianceCache":
        return IrradianceCache.concatenate([self, other])

    @staticmethod
    def concatenate(parts: list) -> "IrradianceCache":
        """The records of ``parts`` (a non-empty list of caches) in order, each column copied once: joining
        many caches pairwise copies the growing front again at every step."""
        def joined(f):
            columns = [getattr(c, f) for c in parts]
            given = [c for c in columns if c is not None]
            if not given:
                return None
            shape = given[0].shape[1:]  # a sky field: records that gathered no sky have none, read as 0
            return np.concatenate([np.zeros((len(c),) + shape) if column is None else column
                                   for c, column in zip(parts, columns)])
        return IrradianceCache(*(joined(f) for f in IrradianceCache.__dataclass_fields__))

    def take(self, index) -> "IrradianceCache":
        return IrradianceCache(*(None if getattr(self, f) is None else getattr(self, f)[index]
                                 for f in self.__dataclass_fields__))


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
    leave_one_out: bool = False
    """A record at a photon leaves that photon out of its E_k (deviation: leave-one-out)."""
    wall_sectors: bool = True
    """Records find their walls (deviation: wall-sectors); False leaves every sector open."""
    neighbour_clamp: bool = True
    """R_k <= R_j + |p_k - p_j| between records ([KBPZ06]; deviation: neighbour-clamp)."""
    clamp_recovery: bool = False
    """After pass 2's final clamp, Algorithm 1 again over the photons it uncovered (deviation: clamp-recovery)."""
    record_visibility: bool = True
    """Records and hole records' photons off a point's tangent plane count only if they see it
    (deviation: record-visibility)."""
    zone_photons: int = 0
    """R_k >= the distance to the zone_photons-th nearest photon / a, so E_k's zone holds that many
    (deviation: zone-photon-floor, Preview); 0: no floor."""


@dataclass
class Zones:
    """Photons in each record's zone of influence: ``parts[k]`` (int32 indices) for record k.

    Kept as one array per record rather than one concatenated array: the copy would
    double the zones' memory at the moment pass 2 peaks (66 MB for 4M photons).
    """

    parts: list

    def batch(self, s: slice) -> tuple[np.ndarray, np.ndarray]:
        """(lengths (b,), photons (sum,) int64) of records s.start..s.stop-1, in record order."""
        return self._lengths_and_photons(self.parts[s])

    def subset(self, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lengths (b,), photons (sum,) int64) of the records ``index``, in that order."""
        return self._lengths_and_photons([self.parts[i] for i in index])

    @staticmethod
    def _lengths_and_photons(chunk: list) -> tuple[np.ndarray, np.ndarray]:
        lengths = np.array([len(z) for z in chunk], np.int64)
        photons = np.concatenate(chunk).astype(np.int64) if chunk else np.zeros(0, np.int64)
        return lengths, photons


@dataclass
class CacheBuildStats:
    records: int = 0
    kd_queries: int = 0
    candidates_visited: int = 0
    wall_rays: int = 0
    uncovered_after_clamp: list = field(default_factory=list)
    """Photons no record accepted after each final neighbour clamp that recovery answered."""

    def add(self, other: "CacheBuildStats"):
        self.records += other.records
        self.kd_queries += other.kd_queries
        self.candidates_visited += other.candidates_visited
        self.wall_rays += other.wall_rays


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
        placed = cache.R  # each record's R_k when its zone was gathered
        cache.R = neighbour_clamp(cache.p, placed, density.workers)
        rounds = CLAMP_RECOVERY_ROUNDS if params.clamp_recovery else 0
        for round in range(1, rounds + 1):  # deviation: clamp-recovery, docs/DEVIATIONS.md
            uncovered = ~covered_by_zones(density, cache, zones, params.a, placed)
            stats.uncovered_after_clamp.append(int(uncovered.sum()))
            if not uncovered.any():
                break
            if progress is not None:
                progress.begin(f"Pass 2: records for {int(uncovered.sum()):,} photons the neighbour clamp uncovered")
            more, more_zones, more_stats = _recover(density, uncovered, cache, lighting, params, caster,
                                                    np.random.default_rng([seed, STREAM_RECORD_ORDER, round]),
                                                    progress)
            stats.add(more_stats)
            placed = np.concatenate([placed, more.R])
            cache, zones = cache.extend(more), Zones(zones.parts + more_zones.parts)
            cache.R = neighbour_clamp(cache.p, cache.R, density.workers)
    return cache, zones, lighting, stats


def covered_by_zones(density: PhotonDensity, cache: IrradianceCache, zones: "Zones", a: float,
                     placed: np.ndarray) -> np.ndarray:
    """(N,) bool: photons some record still accepts (Equation 2 with its R_k now) among the photons of its zone.

    A record's zone holds the photons it accepted when placed with R_k = ``placed`` (K,), and the
    neighbour clamp only shrinks R_k, so no other photon can have joined it; a record the clamp left
    alone still accepts its whole zone. The other records' zone photons not covered already are
    weighed again, in chunks of records, the least shrunk first (they cover the most, so fewer pairs
    remain for the rest)."""
    covered = np.zeros(len(density.p), bool)
    lib = native_kernels.library()
    if lib is not None:  # Equations 1-2 over the pairs in C, as Equation 3's lookups weigh them
        p64, n64 = np.ascontiguousarray(density.p, np.float64), density.n.astype(np.float64)
    shrink = cache.R / np.maximum(placed, 1e-300)
    kept = np.flatnonzero(shrink >= 1.0)
    for s in slices(len(kept), CLAMP_CHUNK * 8):
        covered[zones.subset(kept[s])[1]] = True
    again = np.flatnonzero(shrink < 1.0)
    again = again[np.argsort(-shrink[again], kind="stable")]
    for s in slices(len(again), CLAMP_CHUNK):
        lengths, photons = zones.subset(again[s])
        owner = np.repeat(again[s], lengths)
        open_ = np.flatnonzero(~covered[photons])
        photons, owner = photons[open_], owner[open_]
        if lib is not None:
            ok = native_kernels.ward_accept(lib, p64, n64, cache.p, cache.n, cache.R, 0.0, a, photons, owner)[1]
        else:
            P, N = density.p[photons].astype(np.float64), density.n[photons].astype(np.float64)
            p_k, n_k, R_k = cache.p[owner], cache.n[owner], cache.R[owner]
            ok = accepted(ward_weight(P, N, p_k, n_k, R_k), a, P, N, p_k, n_k, R_k)
        covered[photons[ok]] = True
    return covered


def _recover(density: PhotonDensity, uncovered: np.ndarray, cache: IrradianceCache, lighting: PhotonLighting,
             params: CacheParameters, caster, rng: np.random.Generator, progress=None
             ) -> tuple[IrradianceCache, "Zones", "CacheBuildStats"]:
    """Algorithm 1 over the ``uncovered`` (N,) photons, clamped against ``cache``: the new records, their
    zones and counters. Their Ward weights and w_k E_k join every photon's section 3.1 sums in ``lighting``."""
    threshold = 1.0 / params.a
    w_sum = np.where(uncovered, 0.0, threshold)  # the walk visits the uncovered photons only
    E_sum = np.zeros((len(w_sum), 3))
    before = w_sum.copy()
    more, zones, stats = place_records(density, density.p, density.n, w_sum, E_sum, params, rng,
                                       candidate_is_photon=True, progress=progress, existing=cache, caster=caster)
    lighting.w_sum[:] += (w_sum - before).astype(lighting.w_sum.dtype)
    lighting.E_indirect_sum[:] += E_sum.astype(lighting.E_indirect_sum.dtype)
    return more, zones, stats


def cache_for_holes(density: PhotonDensity, cand_p: np.ndarray, cand_n: np.ndarray, params: CacheParameters,
                    rng: np.random.Generator, existing: IrradianceCache, caster=None, estimate: bool = True,
                    shared=None) -> tuple[IrradianceCache, Zones, CacheBuildStats]:
    """Section 3.4: Algorithm 1 over texel samples (c, 3) no record covers; records flagged ``hole``.

    estimate : False leaves E_k (and photons_used) 0 and the zones empty, for records that final
        gathering will give their E_k without reading their zone's photons: the density estimate
        (its surface coverage rays and photon queries) would be thrown away.
    shared : the bake's :class:`~core.zone_grid.SharedZones`, whose records ``existing`` begins with, or None.
    """
    return place_records(density, cand_p, cand_n, np.zeros(len(cand_p)), np.zeros((len(cand_p), 3)), params, rng,
                         candidate_is_photon=False, existing=existing, caster=caster, estimate=estimate,
                         shared=shared)


# --------------------------------------------------------------------------- Algorithm 1
def place_records(density: PhotonDensity, cand_p: np.ndarray, cand_n: np.ndarray, w_sum: np.ndarray,
                  E_sum: np.ndarray, params: CacheParameters, rng: np.random.Generator,
                  candidate_is_photon: bool, progress=None, existing: IrradianceCache | None = None,
                  caster=None, estimate: bool = True, shared=None) -> tuple[IrradianceCache, Zones, CacheBuildStats]:
    """The record-placement loop of Algorithm 1 over a generic candidate set, in blocks.

    cand_p, cand_n : (c, 3) float64 candidate positions and normals.
    w_sum, E_sum : (c,) and (c, 3) running sums, updated in place.
    candidate_is_photon : candidates are the photons themselves (pass 2), so a
        zone's photons are the candidates to update; otherwise (holes) the
        candidates within the zone are found by their own kd-tree.
    existing : records already placed (neighbour clamping also looks at them).
    caster : a :class:`core.rays.RayCaster` over the scene; with it each record finds the walls
        in its tangent plane (:func:`~core.record_walls.wall_distances`), past which it is not used.
    estimate : as :func:`cache_for_holes` (candidates other than photons only).
    shared : as :func:`cache_for_holes`.
    """
    threshold = 1.0 / params.a
    stats = CacheBuildStats()
    queries = density.queries
    records = _Records()
    clamp = _NeighbourClamp(existing, params.neighbour_clamp, density.workers, shared)
    cand_tree = None if candidate_is_photon else cKDTree(cand_p)
    order = rng.permutation(len(cand_p))
    slot_of = np.full(len(cand_p), -1, np.int64)  # _accumulate's scratch
    start, size = 0, 32  # the first block is small: it measures how many photons a zone holds
    while start < len(order):
        block, start = _next_block(order, start, w_sum, threshold, size)
        stats.candidates_visited += len(block)
        while len(block):  # records placed in a block may leave some of its candidates uncovered
            R_k = _radii(density, cand_p[block], cand_n[block], params, clamp)
            walked = _walk(cand_p[block], cand_n[block], R_k, params.a, density.workers)
            picked = block[walked]
            R_k = clamp.within(cand_p[picked], R_k[walked])
            new, members, w_members, owner = _create_records(
                density, picked, cand_p[picked], cand_n[picked], R_k, params, caster, cand_tree, cand_p, cand_n,
                candidate_is_photon, stats, estimate or candidate_is_photon)
            _accumulate(w_sum, E_sum, members, w_members, new.E[owner], slot_of)  # Algorithm 1's last line
            # A candidate is covered by its own record even if Equation 2 rounding dropped it.
            short = w_sum[picked] < threshold
            E_sum[picked[short]] += (threshold - w_sum[picked[short]])[:, None] * new.E[short]
            w_sum[picked[short]] = threshold
            records.add(new)
            pairs = max(len(members), sum(map(len, new.zones)))
            size = int(np.clip(_ZONE_PAIRS * len(picked) / max(pairs, 1), 16, _BLOCK))
            clamp.add(new.p, new.R)
            block = block[w_sum[block] < threshold]
        if progress is not None:
            progress.update(min(1.0, start / max(len(order), 1)))
    stats.records = len(records)
    stats.kd_queries += density.queries - queries
    return records.cache(hole=not candidate_is_photon), Zones(records.zones), stats


def _accumulate(w_sum: np.ndarray, E_sum: np.ndarray, members: np.ndarray, w: np.ndarray, E_k: np.ndarray,
                slot_of: np.ndarray):
    """w_sum[c] += w, E_sum[c] += w E_k over (m,) pairs (candidate c, weight w, E_k (m, 3)), in place: each
    candidate's pairs summed first, then added; compiled when the library is there (the same sums as
    :func:`_accumulate_numpy`, which sorts the pairs and adds through fancy indexing: the building's pass 2 spent
    2.0 s there, 0.8-0.95 s compiled). slot_of : (c,) int64 all -1, the kernel's scratch, left so."""
    lib = native_kernels.library()
    if lib is None or not native_kernels.accumulate(lib, w_sum, E_sum, members, w, E_k, slot_of):
        _accumulate_numpy(w_sum, E_sum, members, w, E_k)


def _accumulate_numpy(w_sum: np.ndarray, E_sum: np.ndarray, members: np.ndarray, w: np.ndarray, E_k: np.ndarray):
    """:func:`_accumulate` in numpy (the compiled kernel's reference)."""
    # bincount per channel (np.add.at was 2x slower here), over the touched candidates only: a block's
    # zones hold at most ~_ZONE_PAIRS pairs, and counts over all of Sponza's 2.9 M photons cost 23 MB each.
    touched, slot = np.unique(members, return_inverse=True)
    c = len(touched)
    w_sum[touched] += np.bincount(slot, weights=w, minlength=c)
    for channel in range(3):
        E_sum[touched, channel] += np.bincount(slot, weights=w * E_k[:, channel], minlength=c)


def _next_block(order: np.ndarray, start: int, w_sum: np.ndarray, threshold: float, size: int
                ) -> tuple[np.ndarray, int]:
    """The next ``size`` candidates of ``order`` from ``start`` with w_sum < threshold (fewer at its end),
    and where to go on. Only the scanned part of ``order`` is read (blocks can be a few dozen candidates)."""
    found, count = [], 0
    while start < len(order) and count < size:
        chunk = order[start:start + 4 * size]
        at = np.flatnonzero(w_sum[chunk] < threshold)[:size - count]
        if len(at) == size - count:
            start += int(at[-1]) + 1
        else:
            start += len(chunk)
        found.append(chunk[at])
        count += len(at)
    return (np.concatenate(found) if found else np.zeros(0, np.int64)), start


def _radii(density: PhotonDensity, p: np.ndarray, n: np.ndarray, params: CacheParameters,
           clamp: "_NeighbourClamp") -> np.ndarray:
    """(B,) R_k at B candidates: Figure 3, kept in [R_min, R_max], clamped against the records so far."""
    R_k = density.harmonic_mean_distances(p, n, params.r_nearest, params.R_max)
    if params.zone_photons:  # deviation: zone-photon-floor, docs/DEVIATIONS.md
        R_k = np.maximum(R_k, density.photon_reach(p, n, params.zone_photons) / params.a)
    return clamp.clamp(p, np.clip(R_k, params.R_min, params.R_max))


def _walk(p: np.ndarray, n: np.ndarray, R_k: np.ndarray, a: float, workers: int = 1) -> np.ndarray:
    """Positions of the candidates (B, 3) the sequential walk over them would place records at.

    Candidate i gets a record unless the record of an earlier picked candidate j accepts it
    (Equation 2 with R_j). Resolved in rounds, each deciding every candidate whose earlier
    coverers are decided; the result is the sequential walk's, rounds ~ the longest chain.
    """
    lengths, i = ball_pairs(cKDTree(p), p, a * R_k, workers)
    j = np.repeat(np.arange(len(p)), lengths)
    keep = i > j
    j, i = j[keep], i[keep]
    keep = accepted(ward_weight(p[i], n[i], p[j], n[j], R_k[j]), a, p[i], n[i], p[j], n[j], R_k[j])
    j, i = j[keep], i[keep]
    state = np.zeros(len(p), np.int8)  # 0 undecided, 1 record, 2 covered by an earlier record
    while len(i):
        undecided = state == 0
        waiting = np.zeros(len(p), bool)
        waiting[i[state[j] != 2]] = True  # an earlier coverer is undecided or a record
        covered = np.zeros(len(p), bool)
        covered[i[state[j] == 1]] = True
        state[undecided & covered] = 2
        state[undecided & ~waiting] = 1
        live = state[i] == 0
        j, i = j[live], i[live]
    state[state == 0] = 1
    return np.flatnonzero(state == 1)


def _create_records(density, picked, p_k, n_k, R_k, params: CacheParameters, caster, cand_tree, cand_p, cand_n,
                    candidate_is_photon: bool, stats: CacheBuildStats, estimate: bool = True):
    """B records of Algorithm 1 at candidates ``picked`` (B,) (p_k, n_k (B, 3), R_k (B,)): walls, E_k and
    what they cover. estimate : False skips E_k (0) and the zones (empty), see :func:`cache_for_holes`.

    Returns (the records as a :class:`_Chunk`, covered candidates (m,), their w (m,), their record (m,)).
    """
    a, B = params.a, len(p_k)
    wall = None
    if caster is not None and params.wall_sectors:  # deviation: wall-sectors, docs/DEVIATIONS.md
        wall = wall_distances(caster, p_k, n_k, a * R_k)
        stats.wall_rays += WALL_RAYS * B
    # Walls limit where a record is *used* (interpolation, hole coverage). A record at a photon
    # estimates E_k and lends virtual rays from its whole disc: cutting those discs at every corner
    # of a room removes most of the photons a corner record has, which made Preview noisier and
    # pass 3 cast more real rays. A hole record may sit where no photon arrives (behind a thin
    # wall); there photons past a wall would leak light in, so its estimate stops at its walls, and
    # photons off its tangent plane that cannot see it (a closed box's inside) are not its own.
    est_wall = None if candidate_is_photon else wall
    est_caster = caster if not candidate_is_photon and params.record_visibility else None  # deviation: record-visibility
    if estimate:
        coverage = None
        if caster is not None and params.kernel_coverage:  # deviation: surface-coverage, docs/DEVIATIONS.md
            coverage = surface_coverages(caster, p_k, n_k, a * R_k, est_wall,
                                         density.lit_back_faces(caster.face_normals))
            stats.wall_rays += COVERAGE_RINGS * COVERAGE_ANGLES * B
        own = picked if candidate_is_photon and params.leave_one_out else None  # deviation: leave-one-out
        zone = density.records(p_k, n_k, R_k, a, est_wall, coverage, est_caster, own)
    else:
        zone = ZoneEstimates(np.zeros(B, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((B, 3)),
                             np.zeros(B, np.int64))
    chunk = _Chunk(p_k, n_k, zone.E_k, R_k, zone.used, wall, np.split(zone.photons, np.cumsum(zone.lengths)[:-1]))
    if candidate_is_photon:
        return chunk, zone.photons, zone.w, np.repeat(np.arange(B), zone.lengths)
    lengths, members = ball_pairs(cand_tree, p_k, a * R_k, density.workers)
    owner = np.repeat(np.arange(B), lengths)
    stats.kd_queries += B
    P, N = cand_p[members], cand_n[members]
    w = ward_weight(P, N, p_k[owner], n_k[owner], R_k[owner])
    ok = accepted(w, a, P, N, p_k[owner], n_k[owner], R_k[owner])
    if wall is not None:
        ok[ok] = ~beyond_wall(wall[owner[ok]], P[ok] - p_k[owner[ok]], n_k[owner[ok]])
    return chunk, members[ok], w[ok], owner[ok]


@dataclass
class _Chunk:
    """B records placed together: p, n, E (B, 3), R (B,), used (B,), wall (B, S) or None, zones (B arrays)."""

    p: np.ndarray
    n: np.ndarray
    E: np.ndarray
    R: np.ndarray
    used: np.ndarray
    wall: np.ndarray | None
    zones: list


class _Records:
    """Records as they are placed, chunk by chunk, assembled into an :class:`IrradianceCache` at the end."""

    def __init__(self):
        self.chunks, self.zones = [], []

    def __len__(self) -> int:
        return len(self.zones)

    def add(self, chunk: _Chunk):
        self.chunks.append(chunk)
        self.zones.extend(z.astype(np.int32) for z in chunk.zones)

    def cache(self, hole: bool) -> IrradianceCache:
        K = len(self)
        join = lambda name, shape: (np.concatenate([getattr(c, name) for c in self.chunks]).astype(  # noqa: E731
            np.float64).reshape(shape) if self.chunks else np.zeros(shape))
        walls = [c.wall if c.wall is not None else open_walls(len(c.p)) for c in self.chunks]
        return IrradianceCache(
            p=join("p", (K, 3)), n=join("n", (K, 3)), E=join("E", (K, 3)), R=join("R", (K,)),
            grad_r=np.zeros((K, 3, 3)), grad_t=np.zeros((K, 3, 3)),
            photons_used=join("used", (K,)).astype(np.int32), hole=np.full(K, hole),
            refined=np.zeros(K, bool),
            wall=np.concatenate(walls).astype(np.float32) if walls else open_walls(0))


# --------------------------------------------------------------------------- neighbour clamping [KBPZ06]
def neighbour_clamp(p: np.ndarray, R: np.ndarray, workers: int = 1) -> np.ndarray:
    """One min-plus pass: R_k <- min_j (R_j + |p_k - p_j|) over neighbours within R_k ([KBPZ06]).

    Only a neighbour closer than R_k can lower R_k, so each record queries its own ball (one
    query over the largest R pairs every record with thousands of others on a scene whose zones
    span centimetres to metres). The result satisfies R_k <= R_j + |p_k - p_j| for every pair,
    so a single pass is final.
    """
    if len(p) < 2:
        return R.copy()
    out = R.copy()
    tree = cKDTree(p)
    # In chunks of records: a ball query's pairs are Python ints (~40 bytes each), and records of
    # metre-sized R pair with thousands of others (Sponza 2048^2's 74k hole records: 3.4 GB at once).
    # Each chunk's answer is its own: the threads take chunks, not a share of each chunk's query.
    chunks = slices(len(p), CLAMP_CHUNK)
    if workers > 1 and len(chunks) > 1:
        with ThreadPoolExecutor(workers) as pool:
            parts = list(pool.map(lambda s: _clamped(tree, p, R, p[s], R[s], 1), chunks))
    else:
        parts = [_clamped(tree, p, R, p[s], R[s], workers) for s in chunks]
    for s, part in zip(chunks, parts):
        out[s] = part
    return out


def _clamped(tree: cKDTree, p_j: np.ndarray, R_j: np.ndarray, p: np.ndarray, R: np.ndarray, workers: int
             ) -> np.ndarray:
    """(B,) min(R, min_j R_j + |p - p_j|) for B points (p (B, 3), R (B,)) against the records of ``tree``
    (p_j, R_j > 0); only records within R can lower R.

    The records within R are the ball query's; but its pairs are Python ints, and on Sponza 16/m
    a record of metre-sized R pairs with thousands (48 M pairs in pass 2's clamps). The
    CLAMP_NEIGHBOURS nearest settle most points: all of the ball when the last of them lies beyond R,
    else whenever no record past it can do better (each is at least its distance d_k away and has
    R_j >= min R_j). Only the rest ask for their ball; the result is the ball query's, bit for bit.
    """
    out = np.array(R, np.float64)
    B, n = len(p), tree.n
    if B == 0 or n == 0:
        return out
    k = min(CLAMP_NEIGHBOURS, n)
    dist, idx = tree.query(p, k=k, distance_upper_bound=float(R.max()), workers=workers)
    dist, idx = dist.reshape(B, k), idx.reshape(B, k)
    found = idx < n
    j = np.where(found, idx, 0)
    value = np.take(R_j, j) + norms(np.take(p_j, j, axis=0) - p[:, None])
    out = np.minimum(out, np.where(found, value, np.inf).min(axis=1))
    # A record beyond d_k cannot go below d_k + min R_j; the margin covers the kd-tree's distance
    # and norms() differing in the last bits.
    R_least = float(R_j.min())
    bound = (dist[:, -1] + R_least) * (1.0 - 1e-12)
    rows = np.flatnonzero(found[:, -1] & (dist[:, -1] < R) & (out >= bound))
    if len(rows):
        # Nor can one farther than out - min R_j: the ball needs no more (a hole sample's R_k of metres
        # paired it with thousands of records, listed one Python int at a time).
        reach = np.minimum(R[rows], (out[rows] - R_least) * (1.0 + 1e-12))
        lengths, j = ball_pairs(tree, p[rows], reach, workers)
        owner = np.repeat(rows, lengths)
        np.minimum.at(out, owner, np.take(R_j, j) + norms(np.take(p_j, j, axis=0) - np.take(p, owner, axis=0)))
    return out


class _NeighbourClamp:
    """R_k <= R_j + |p_k - p_j| against the records placed so far ([KBPZ06]).

    The records are kept in kd-trees of doubling sizes (a new chunk merges with the last tree
    while that is no more than twice as large), so each record is re-indexed O(log K) times.
    """

    def __init__(self, existing: IrradianceCache | None, enabled: bool = True, workers: int = 1, shared=None):
        """shared : a :class:`~core.zone_grid.SharedZones` whose records ``existing`` may begin with: their
        kd-tree is then its, built once per bake (the clamp is a minimum over all records, however split)."""
        self.enabled, self.workers = enabled, workers
        self.levels = []  # (p (k, 3), R (k,), tree)
        if enabled and existing is not None and len(existing):
            R = np.asarray(existing.R, np.float64)
            if shared is not None and shared.starts(existing.p, R, shared.R):
                self.levels.append(shared.clamp_level())
                self.add(existing.p[len(shared.p):], R[len(shared.p):])
            else:
                self.add(existing.p, existing.R)

    def clamp(self, p: np.ndarray, R: np.ndarray) -> np.ndarray:
        """(B,) R clamped against every record so far (p (B, 3), R (B,))."""
        R = np.array(R, np.float64)
        if not self.enabled:
            return R
        for p_j, R_j, tree in self.levels:
            R = _clamped(tree, p_j, R_j, p, R, self.workers)
        return R

    def within(self, p: np.ndarray, R: np.ndarray) -> np.ndarray:
        """(B,) R of B records placed in this order clamped against the earlier ones among them.

        R_k <- min(R_k, min_{j<k} R_j + |p_k - p_j|): by the triangle inequality this equals
        clamping each record against the already clamped earlier ones, as a sequential walk does.
        """
        R = np.array(R, np.float64)
        if not self.enabled or len(p) < 2:
            return R
        lengths, j = ball_pairs(cKDTree(p), p, R, self.workers)
        k = np.repeat(np.arange(len(p)), lengths)
        earlier = j < k
        k, j = k[earlier], j[earlier]
        np.minimum.at(R, k, R[j] + norms(np.take(p, j, axis=0) - np.take(p, k, axis=0)))
        return R

    def add(self, p: np.ndarray, R: np.ndarray):
        if not self.enabled or len(p) == 0:
            return
        while self.levels and len(self.levels[-1][0]) <= 2 * len(p):
            p_old, R_old, _ = self.levels.pop()
            p, R = np.concatenate([p_old, p]), np.concatenate([R_old, R])
        self.levels.append((p, R, cKDTree(p)))
