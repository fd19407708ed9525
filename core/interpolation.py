"""Irradiance at arbitrary surface points from the cache: Equations 1 to 3 over many points.

Equation 2 accepts record k at p only inside its zone of influence,
``|p - p_k| <= a R_k``, so the candidate pairs come from a grid over the zones
(:mod:`core.zone_grid`, built once per lookup): exactly the records that may be
accepted, with no cap on how many, at a fixed cost per point whether the points
are a chunk of neighbouring texels or pass 3's hits spread over the scene.
A pure function of its chunk of points.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field
import numpy as np
from . import native_kernels
from .constants import OFF_PLANE, RECORD_STEP_BEHIND
from .executor import TEXEL_CHUNK, slices
from .irradiance_cache import IrradianceCache
from .record_walls import beyond_wall_and_reach, wall_clearance
from .vectors import dots
from .ward import accepted, record_estimate, ward_weight
from .zone_grid import CELL_PER_ZONE, SharedZones, ZoneGrid, cell_per_zone


@dataclass
class CacheLookup:
    """Equation 3 against a fixed cache (read-only, so chunks may run on several threads)."""

    cache: IrradianceCache
    a: float
    use_gradients: bool = True
    caster: object = None
    """A :class:`core.rays.RayCaster`: with it a record off a point's tangent plane must see the point
    (deviation: record-visibility); None accepts records by Equation 2 and their walls alone."""
    margin: float = 0.0
    """Zones widened by this distance, scene units (deviation: gap-fill): the zone radius becomes
    a R_k + margin and Equation 1's distance term uses R_k + margin / a; the normal term is unchanged.
    Past its own zone a record's walls are unknown, so there it counts only if it sees the point
    (one ray; needs ``caster``)."""
    layers: bool = False
    """Also test, with ``caster``, a record behind the point's plane while the point lies in front of the
    record's own: a layer under the point's surface (an emissive panel a millimetre under a ceiling read
    the gap's records). Final's records gathered their E_k at their own points, so such a record holds
    another hemisphere's light; Preview's hold their discs' photons, layers mixed (its texel lookups go
    without: the occluded building's Preview 22.8 -> 24.5 % with it)."""
    sky: bool = False
    """Interpolate the records' gathered sky (deviation: sky-gathering) with their E_k, same weights:
    E comes out (m, 6), the sky in channels 3-5. Needs a cache with E_sky."""
    cell_per_zone: float = CELL_PER_ZONE
    """The zone grid's cell side in median zone radii (:func:`core.zone_grid.cell_per_zone`); the pairs
    found, and so E, do not depend on it."""
    shared: SharedZones | None = None
    """The bake's grid over records this cache starts with, reused instead of a grid of its own (not with a
    margin, which widens the zones); the pairs, and so E, are the same."""
    own_zone: np.ndarray = field(init=False, repr=False)
    """(K,) a R_k, the records' zones before any gap-fill margin."""
    zone: np.ndarray = field(init=False, repr=False)
    clearance: np.ndarray = field(init=False, repr=False)
    grid: ZoneGrid = field(init=False, repr=False)

    def __post_init__(self):
        self.own_zone = self.a * np.asarray(self.cache.R, dtype=np.float64)
        self.zone = self.own_zone + self.margin
        self.clearance = wall_clearance(self.cache.wall)
        if self.shared is not None and self.margin == 0:
            self.grid = self.shared.grid(self.cache.p, self.zone, self.cell_per_zone)
        else:
            self.grid = ZoneGrid(self.cache.p, self.zone, self.cell_per_zone)
        self.values = texel_values(self.cache, self.sky)

    def candidates(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rows, records): every (point, record) pair with the point inside the record's zone,
        each point's records in ascending order (Equation 3 sums them in that order)."""
        return self.grid.pairs(p)

    def irradiance(self, p: np.ndarray, n: np.ndarray, pairs: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Equation 3 at points p (m, 3) with unit normals n (m, 3).

        Returns (E (m, 3) float64 >= 0, or (m, 6) with :attr:`sky`, w_sum (m,) float64); w_sum == 0
        marks a hole (no record accepted), where E is 0. pairs : :meth:`candidates` of p, when the
        caller looks up the same points more than once (both sides of a surface).
        """
        E, w_sum, _ = self._equation_3(p, n, with_zone=False, pairs=pairs)
        return E, w_sum

    def irradiance_and_zone(self, p: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`irradiance` plus (m,) the smallest zone radius a R_k accepted at each point (inf: none).

        The smallest zone bounds how fast Equation 3 can change around the point.
        """
        return self._equation_3(p, n, with_zone=True)

    def _equation_3(self, p: np.ndarray, n: np.ndarray, with_zone: bool, pairs: tuple | None = None):
        m = len(p)
        E_k, grad_r, grad_t = self.values
        c = self.cache
        rows, rec = self.candidates(p) if pairs is None else pairs
        if not len(rows):
            return np.zeros((m, E_k.shape[1])), np.zeros(m), np.full(m, np.inf)
        lib = native_kernels.library()
        if lib is None:
            w, ok, d2 = ward_pairs(p, n, c.p, c.n, c.R, self.margin / self.a, self.a, rows, rec)
        else:
            w, ok, d2 = native_kernels.ward_accept(lib, p, n, c.p, c.n, c.R, self.margin / self.a, self.a, rows, rec)

        def pair_vectors(i):
            """(p, n at the points; p_k, n_k of the records; p - p_k) of pairs i."""
            p_r, p_k = np.take(p, rows[i], axis=0), np.take(c.p, rec[i], axis=0)
            return p_r, np.take(n, rows[i], axis=0), p_k, np.take(c.n, rec[i], axis=0), p_r - p_k

        own_zone = self.own_zone
        near_wall = ok & (d2 >= self.clearance[rec] ** 2)
        # deviation: wall-sectors: a point past a wall met by one sector ray only, in the wedge
        # between the polygons whose missed rays stand at the zone's radius and far away, counts
        # if the record sees it (a floor running on under a wall, not the floor beside a column).
        walled = np.flatnonzero(near_wall)
        if len(walled):
            past_reach, past_far = pair_walls(lib, rows[walled], rec[walled], p, c.p, c.n, c.wall, own_zone)
            inside, band = ~past_reach, past_reach & ~past_far
            if self.caster is not None and band.any():
                p_r, n_r, p_k, n_k, _ = pair_vectors(walled[band])
                inside[band] = self.caster.sides_visible(p_r, n_r, p_k, n_k)
            ok[walled] = inside
        if self.caster is not None:  # a surface between point and record hides it (a closed box's inside)
            kept = np.flatnonzero(ok)
            p_r, n_r, p_k, n_k, delta = pair_vectors(kept)
            seen = ~self.caster.hidden_off_plane(p_r, n_r, p_k, n_k)
            # ... and one behind it past the plane's curvature (a step down: see RECORD_STEP_BEHIND), or
            # any distance behind it while the point lies in front of the record's own plane: a layer
            # under the point's surface (on a convex surface each lies behind the other's plane).
            depth = np.einsum("ij,ij->i", delta, n_r)
            step = depth > RECORD_STEP_BEHIND * own_zone[rec[kept]]
            if self.layers:
                off = OFF_PLANE * self.caster.epsilon
                step |= (depth > off) & (np.einsum("ij,ij->i", delta, n_k) > off)
            behind = np.flatnonzero(seen & step)
            if len(behind):
                seen[behind] = self.caster.sides_visible(p_r[behind], n_r[behind], p_k[behind], n_k[behind])
            ok[kept] = seen
        at = None
        if self.margin > 0:  # deviation: gap-fill: past the record's own zone, walls are unknown
            past = np.flatnonzero(ok & (d2 >= own_zone[rec] ** 2))
            if len(past):
                ok[past] = self.caster is not None and self.caster.sides_visible(*pair_vectors(past)[:4])
            # deviation: gap-fill: a gradient holds over its own zone; past it E_k stays as at its edge.
            kept = np.flatnonzero(ok)
            _, _, p_k, _, delta = pair_vectors(kept)
            scale = np.minimum(1.0, own_zone[rec[kept]] / np.maximum(np.sqrt(d2[kept]), 1e-300))
            at = p_k + delta * scale[:, None]
        rows, rec, w = rows[ok], rec[ok], w[ok]
        grads = (grad_r, grad_t) if self.use_gradients else (None, None)
        zone = self.zone if with_zone else None
        if lib is None:
            num, den, smallest = equation3_sums(m, p, n, at, c.p, c.n, E_k, *grads, zone, rows, rec, w)
        else:
            num, den, smallest = native_kernels.equation3_sums(lib, m, p, n, at, c.p, c.n, E_k, *grads, zone,
                                                               rows, rec, w)
        E = np.divide(num, den[:, None], out=np.zeros_like(num), where=den[:, None] > 0)
        return E, den, np.full(m, np.inf) if smallest is None else smallest


def pair_walls(lib, rows: np.ndarray, rec: np.ndarray, p: np.ndarray, p_k: np.ndarray, n_k: np.ndarray,
               wall: np.ndarray, reach: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~core.record_walls.beyond_wall_and_reach` for the pairs (rows, rec) (w,) of points p (m, 3) and
    records p_k, n_k (K, 3) with walls ``wall`` (K, WALL_RAYS) and ``reach`` (K,), compiled when ``lib`` is
    the library (:func:`core.native_kernels.pair_walls`)."""
    if lib is not None:
        return native_kernels.pair_walls(lib, rows, rec, p, p_k, n_k, wall, reach)
    return beyond_wall_and_reach(wall[rec], np.take(p, rows, axis=0) - np.take(p_k, rec, axis=0),
                                 np.take(n_k, rec, axis=0), reach[rec])


def ward_pairs(p, n, p_k, n_k, R, R_add: float, a: float, rows, rec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Equations 1 and 2 over the pairs (rows, rec) of points p, n (m, 3) and records p_k, n_k (K, 3) of
    radius R + R_add: (w, accepted, |p - p_k|^2), each (pairs,) (:func:`core.native_kernels.ward_accept`
    compiled)."""
    p_r, n_r = np.take(p, rows, axis=0), np.take(n, rows, axis=0)
    p_k, n_k, R_k = np.take(p_k, rec, axis=0), np.take(n_k, rec, axis=0), R[rec] + R_add
    w = ward_weight(p_r, n_r, p_k, n_k, R_k)
    delta = p_r - p_k
    return w, accepted(w, a, p_r, n_r, p_k, n_k, R_k), dots(delta, delta)


def equation3_sums(m: int, p, n, at, p_k, n_k, E_k, grad_r, grad_t, zone, rows, rec, w):
    """Equation 3's sums over the accepted pairs (rows, rec) with weights w, in pair order: num (m, c) of
    w E_rec (record k's estimate extrapolated to ``at`` (pairs, 3), or to p[rows] when None, clamped at
    0), den (m,) of w, and (m,) the smallest zone[rec] per point (None without zone).
    (:func:`core.native_kernels.equation3_sums` compiled.)"""
    num = np.zeros((m, E_k.shape[1]))
    n_r = np.take(n, rows, axis=0)
    E_rec = record_estimate(E_k[rec], np.take(p, rows, axis=0) if at is None else at, n_r,
                            np.take(p_k, rec, axis=0), np.take(n_k, rec, axis=0),
                            None if grad_r is None else grad_r[rec], None if grad_t is None else grad_t[rec])
    E_rec = np.maximum(E_rec, 0.0)
    for ch in range(E_k.shape[1]):
        num[:, ch] = np.bincount(rows, weights=w * E_rec[:, ch], minlength=m)
    den = np.bincount(rows, weights=w, minlength=m)
    smallest = None
    if zone is not None:
        smallest = np.full(m, np.inf)
        np.minimum.at(smallest, rows, zone[rec])
    return num, den, smallest


def interpolate(cache: IrradianceCache, a: float, gradients: bool, p: np.ndarray, n: np.ndarray, executor,
                progress, with_zone: bool = False, caster=None, margin: float = 0.0, sky: bool = False,
                layers: bool = False, shared: SharedZones | None = None, rows: np.ndarray | None = None) -> tuple:
    """Equation 3 at points p, n (m, 3), chunked over the executor: (E (m, 3), w_sum (m,)), plus
    (m,) the smallest accepted zone radius ``with_zone`` (see :meth:`CacheLookup.irradiance_and_zone`).
    rows : (m,) the points' rows of p and n, when they are some of a larger set's: each chunk takes its own
        (a copy of millions of rows up front is fresh memory, faulted in on one thread; a Dask executor ships
        p and n whole), or None.
    sky : E (m, 6) with the records' gathered sky in channels 3-5 (see :attr:`CacheLookup.sky`).

    caster : a :class:`core.rays.RayCaster` (deviation: record-visibility, see :attr:`CacheLookup.caster`);
        its ``rays_cast`` counts the visibility rays.
    margin : zones widened by this distance (deviation: gap-fill, see :attr:`CacheLookup.margin`).
    layers : test records in a layer under the point's surface too (see :attr:`CacheLookup.layers`).
    shared : the bake's zone grid over the records ``cache`` starts with (see :attr:`CacheLookup.shared`).
    """
    m = len(p) if rows is None else len(rows)
    lookup = CacheLookup(cache, a, gradients, margin=margin, sky=sky, layers=layers,
                         cell_per_zone=cell_per_zone(m, len(cache)), shared=shared)

    def run(index, s):
        chunk = copy.copy(lookup)  # shares the cache's arrays; a view of the BVH per chunk counts its own rays
        if caster is not None:
            chunk.caster = caster.serial()
        at = s if rows is None else rows[s]
        part = (chunk.irradiance_and_zone if with_zone else chunk.irradiance)(p[at], n[at])
        return part, chunk.caster.rays_cast if caster is not None else 0  # returned: a Dask chunk runs elsewhere

    results = executor.map_chunks(run, slices(m, TEXEL_CHUNK), progress)
    parts = [part for part, _ in results]
    if caster is not None:
        caster.rays_cast += sum(rays for _, rays in results)
    if not parts:
        parts = [(np.zeros((0, 6 if sky else 3)), np.zeros(0), np.zeros(0))[:3 if with_zone else 2]]
    return tuple(np.concatenate([part[i] for part in parts]) for i in range(len(parts[0])))


def texel_values(cache: IrradianceCache, sky: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(E_k (K, c), grad_r, grad_t (K, c, 3)) the records carry to a lookup: their indirect irradiance,
    and with ``sky`` their gathered sky beside it (c = 6; deviation: sky-gathering)."""
    if not sky:
        return cache.E, cache.grad_r, cache.grad_t
    if not cache.has_sky:
        raise ValueError("CacheLookup(sky=True) needs records that gathered the sky (IrradianceCache.E_sky)")
    return (np.concatenate([cache.E, cache.E_sky], axis=1), np.concatenate([cache.grad_r, cache.grad_r_sky], axis=1),
            np.concatenate([cache.grad_t, cache.grad_t_sky], axis=1))
