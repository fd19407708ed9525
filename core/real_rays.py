"""Real gathering rays of pass 3 (Figure 4c): cast through hemisphere cells, shaded at their hits.

A real ray's radiance is albedo at the hit x (E_direct + E_indirect) / pi. E_indirect is pass 2's
cache interpolated at the hit (Equation 3). The paper takes the nearest photon's stored
irradiance, which is that same interpolation at the photon ([Chr99]); interpolating at the hit
itself respects the records' walls, where the nearest photon may lie on the lit side of a thin
wall for a hit in the dark room behind it (tests/test_stability.py). E_direct is computed at the
hit with one shadow-ray sample per light: the nearest photon's direct irradiance is biased
toward the denser, brighter side wherever direct light varies fast (+21 % on the Cornell floor,
lit mostly by the ceiling's hot spot above the point light), and one shadow ray costs less than
the gathering ray that found the hit.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, replace

import numpy as np

from . import native_kernels
from .albedo import albedo as albedo_at
from .constants import (CORNER_HEIGHT, CORNER_REACH, GAP_COS, GAP_WALK_BOUNCES, GAP_WALK_SURVIVAL, HIT_GRID_NEAR,
                        TRANSPARENT_MAX_LAYERS)
from .light_selection import gathering_direct
from .gather_cells import CellSums
from .photon_fallback import NOT_ASKED, NearestPhotons, lent_irradiance, nearest_photon_seen
from .rays import offset_origins
from .sampling import cosine_directions
from .vectors import dots
from .zone_grid import spatial_order


@dataclass(frozen=True)
class RealHits:
    """Where a batch's real rays ended, waiting to be shaded (struct of arrays, h hits).

    cell : (h,) int64 flat cells (record * C + cell) of the rays that hit something.
    triangle : (h,) int64; barycentric : (h, 2) float64; q : (h, 3) float64 hit points;
    direction : (h, 3) float64 unit ray directions; t : (h,) float64 their distances from the record.
    """

    cell: np.ndarray
    triangle: np.ndarray
    barycentric: np.ndarray
    q: np.ndarray
    direction: np.ndarray
    t: np.ndarray

    @staticmethod
    def concatenate(parts: list["RealHits"]) -> "RealHits":
        return RealHits(*(np.concatenate([getattr(part, f) for part in parts]) for f in
                          ("cell", "triangle", "barycentric", "q", "direction", "t")))


def trace_real(caster, frames, cells: np.ndarray, sums: CellSums, rng: np.random.Generator,
               sky: np.ndarray | None = None) -> tuple[RealHits, np.ndarray, np.ndarray]:
    """Cast one real ray through each given cell (flat record * C + cell, each at most once) into ``sums``.

    frames : (p_k, t1, t2, n) of the batch's records, each (B, 3). The rays' directions and
    distances enter ``sums`` now; their radiance once :func:`shade_real` has shaded the hits.
    sky : the world's radiance (3,), which escaping rays bring to the sky channels (deviation:
    sky-gathering), or None.
    Returns the hits and the per-record (B,) sums of 1 / hit distance and hit counts these rays added.
    """
    w_local, d_world, origin = gathering_rays(caster, sums.H, cells, rng.random((len(cells), 2)), frames)
    hits = caster.intersect(origin, d_world, unit=True)
    if sky is not None:  # the rays that escaped; what glass passes: through_glass
        sums.add_sky(cells[~hits.hit], sky)
    hit, q, inv_sum, inv_n = tally_real_rays(sums, cells, w_local, hits, origin, d_world)
    found = RealHits(np.take(cells, hit), np.take(hits.triangle, hit), np.take(hits.barycentric, hit, axis=0), q,
                     np.take(d_world, hit, axis=0), np.take(hits.t, hit))
    sums.add_distances(inv_sum, inv_n)
    return found, inv_sum, inv_n


def gathering_rays(caster, hemisphere, cells: np.ndarray, u: np.ndarray, frames
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(w_local, d_world, origin), each (n, 3): a real ray through each flat cell (record * C + cell) at
    uniform u (n, 2) in its cell (:meth:`Hemisphere.sample_cells`), in world space by its record's frame,
    leaving from the record's point pushed off its surface (:meth:`RayCaster.offset_origins`; hit points are
    that origin plus t). Compiled (:mod:`core.native_kernels`) when the library is there."""
    lib = native_kernels.library()
    if lib is not None:
        return native_kernels.gathering_rays(lib, hemisphere, cells, u, frames, caster.epsilon)
    return gathering_rays_numpy(hemisphere, cells, u, frames, caster.epsilon)


def gathering_rays_numpy(hemisphere, cells: np.ndarray, u: np.ndarray, frames, epsilon: float
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`gathering_rays` in numpy (the compiled kernel's reference)."""
    p_k, t1, t2, n = frames
    C = hemisphere.cells
    rec = cells // C
    w_local = hemisphere.sample_cells(cells % C, u)
    t1_rec, t2_rec, n_rec = (np.take(v, rec, axis=0) for v in (t1, t2, n))
    d_world = w_local[:, :1] * t1_rec + w_local[:, 1:2] * t2_rec + w_local[:, 2:3] * n_rec
    return w_local, d_world, offset_origins(np.take(p_k, rec, axis=0), n_rec, d_world, epsilon)


def tally_real_rays(sums: CellSums, cells: np.ndarray, w_local: np.ndarray, hits, origin: np.ndarray,
                    d_world: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Enter real rays through distinct cells into ``sums`` (:meth:`CellSums.add_real_rays`) and return (the
    rays that hit (h,), their hit points (h, 3), per record (B,) their sums of 1 / distance and their
    counts). Compiled when the library is there."""
    lib = native_kernels.library()
    if lib is not None:
        return native_kernels.tally_real_rays(lib, sums, cells, w_local, hits, origin, d_world)
    return tally_real_rays_numpy(sums, cells, w_local, hits, origin, d_world)


def tally_real_rays_numpy(sums: CellSums, cells: np.ndarray, w_local: np.ndarray, hits, origin: np.ndarray,
                          d_world: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`tally_real_rays` in numpy (the compiled kernel's reference)."""
    sums.add_real_rays(cells, w_local, hits.t)
    hit = np.flatnonzero(hits.hit)
    t = hits.t[hit]
    q = np.take(origin, hit, axis=0) + np.take(d_world, hit, axis=0) * t[:, None]
    rec = cells[hit] // sums.H.cells
    inv_sum = np.bincount(rec, weights=1.0 / np.maximum(t, 1e-300), minlength=sums.B)
    inv_n = np.bincount(rec, minlength=sums.B).astype(np.float64)
    return hit, q, inv_sum, inv_n


def through_glass(caster, hits: RealHits, sums: CellSums, sky: np.ndarray | None = None
                  ) -> list[tuple[RealHits, np.ndarray]]:
    """What real rays find past the glass they met: [(hits behind a layer, their weights (h,)), ...], layer by
    layer, each weight the product of the transmissions tau of the layers passed (up to
    TRANSPARENT_MAX_LAYERS, as shadow rays and photons; deviation: transparent-shadows). A layer's own hit
    is shaded as any hit (its albedo is what it reflects); what lies past it adds tau of its radiance to the
    same cell (:func:`shade_real` with the weights). Rays that escape past a layer bring ``sky`` (3,) times
    their weight to the cell's sky channels (deviation: sky-gathering). Nothing without transmissive
    triangles. The rays cast are counted in ``sums.glass_rays``."""
    out = []
    tau = caster.transmission
    if tau is None or len(hits.cell) == 0:
        return out
    glass = np.flatnonzero(np.take(tau, hits.triangle) > 0)
    weight = np.take(tau, hits.triangle[glass])
    for _ in range(TRANSPARENT_MAX_LAYERS):
        if len(glass) == 0:
            break
        d = hits.direction[glass]
        n_face = np.take(caster.face_normals, hits.triangle[glass], axis=0)
        origin = caster.offset_origins(hits.q[glass], n_face, d)
        found = caster.intersect(origin, d, unit=True)
        sums.glass_rays += len(glass)
        escaped = ~found.hit
        if sky is not None and escaped.any():
            sums.add_sky(hits.cell[glass[escaped]], weight[escaped, None] * sky)
        on = np.flatnonzero(found.hit)
        hits = RealHits(hits.cell[glass[on]], found.triangle[on], found.barycentric[on],
                        origin[on] + d[on] * found.t[on, None], d[on], hits.t[glass[on]] + found.t[on])
        weight = weight[on]
        out.append((hits, weight))
        glass = np.flatnonzero(np.take(tau, hits.triangle) > 0)
        weight = weight[glass] * np.take(tau, hits.triangle[glass])
    return out


def shade_real(scene, caster, sources, hits: RealHits, sums: CellSums, rng: np.random.Generator,
               n_record: np.ndarray | None = None, weight: np.ndarray | None = None) -> tuple[int, int]:
    """Add the radiance at real rays' hits to their cells (one call for all of a batch's rays: the
    cache lookup at hits costs per call as well as per hit). Returns the shadow, fallback and gap rays
    spent and the hits that gathered in a gap. n_record : (B, 3) the batch's record normals
    (deviation: gap-gathering), or None. weight : (h,) what glass on the way passed (:func:`through_glass`)."""
    if len(hits.cell) == 0:
        return 0, 0
    facing = None if n_record is None else np.take(n_record, hits.cell // sums.H.cells, axis=0)
    L, shadow_rays, in_gap = radiance_at_hits(scene, caster, sources, hits.triangle, hits.barycentric, hits.q,
                                              hits.direction, hits.t, rng, facing)
    sums.add_real_radiance(hits.cell, L if weight is None else weight[:, None] * L)
    return shadow_rays, in_gap


def side_met(face_normals: np.ndarray, triangle: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(back (h,) bool: the ray reached its triangle's back side, n (h, 3): the face normal turned toward
    the ray) for rays ``direction`` (h, 3) that hit ``triangle`` (h,)."""
    n_face = np.take(face_normals, triangle, axis=0)
    back = dots(n_face, direction) > 0
    return back, np.where(back[:, None], -n_face, n_face)


def radiance_at_hits(scene, caster, sources, triangle: np.ndarray, barycentric: np.ndarray, q: np.ndarray,
                     direction: np.ndarray, distance: np.ndarray, rng: np.random.Generator,
                     n_record: np.ndarray | None = None) -> tuple[np.ndarray, int, int]:
    """(h, 3) radiance toward the rays, albedo at the hit x (E_direct + E_indirect) / pi, the rays spent
    and how many hits gathered in a gap.

    ``sources`` : :class:`core.refinement.GatherSources`. Where no record accepts the hit
    (w_sum = 0) E_indirect comes from :func:`~core.photon_fallback.nearest_photon_seen`
    (deviation: nearest-photon-fallback): on Sponza a third of the hits are such holes. With
    ``sources.hit_grid`` (deviation: hit-grid) a hit that sees its grid cell's centroid reads
    E_direct + E_indirect and the mean albedo from the cell (one occlusion ray); the rest are shaded
    as above, with their own albedo, and so are hits nearer to the record than HIT_GRID_NEAR times
    their cell centroid's distance from them (``distance`` (h,): each hit's from the record).
    Hits whose surface faces the record's (``n_record`` (h, 3), each hit's record normal), near ones
    and those within ``sources.gap_reach`` of the record, lie in a gap and gather their indirect light
    by a walk of their own (deviation: gap-gathering, :func:`gap_irradiance`); so do hits within
    CORNER_REACH ``sources.gap_reach`` of the record and CORNER_HEIGHT of it above the record's tangent
    plane, at the foot of a surface rising from the record's (deviation: corner-gathering).
    """
    if sources.hit_grid is None:
        _, n_hit = side_met(caster.face_normals, triangle, direction)
        E, rays = _irradiance_at_hits(scene, caster, sources, q, n_hit, rng)
        return albedo_at(scene, triangle, barycentric).astype(np.float64) * E / np.pi, rays, 0
    n_hit, E, centroid, rho, is_open, near, gap = hit_cells(caster, sources, triangle, barycentric, q, direction,
                                                            distance, n_record)
    # deviation: open-cells: in a cell whose centroid sees its corners, a hit sees the centroid.
    far = np.flatnonzero(~near & ~gap & ~is_open)
    alone = near & ~gap
    alone[far] = ~caster.sides_visible(q[far], n_hit[far], centroid[far], n_hit[far])
    own, in_gap = np.flatnonzero(alone), np.flatnonzero(gap)
    rays = len(far)
    if rho is None:
        rho = albedo_at(scene, triangle, barycentric).astype(np.float64)
    elif len(own) or len(in_gap):
        mine = np.flatnonzero(alone | gap)
        rho[mine] = albedo_at(scene, triangle[mine], barycentric[mine])
    if len(own):
        E[own], own_rays = _irradiance_at_hits(scene, caster, sources, q[own], n_hit[own], rng)
        rays += own_rays
    if len(in_gap):
        E[in_gap], gap_rays = gap_irradiance(scene, caster, sources, q[in_gap], n_hit[in_gap], rng)
        rays += gap_rays
    return rho * E / np.pi, rays, len(in_gap)


def hit_cells(caster, sources, triangle: np.ndarray, barycentric: np.ndarray, q: np.ndarray, direction: np.ndarray,
              distance: np.ndarray, n_record: np.ndarray | None) -> tuple:
    """What :func:`radiance_at_hits` knows of gathering hits before it shades any: (n_hit (h, 3) the face
    normal turned toward the ray; the hit-grid cell's E (h, 3), centroid (h, 3), albedo (h, 3) or None and
    openness (h,) bool (:meth:`~core.hit_radiance.HitGrid.lookup`); near (h,) bool, the cell large beside
    the hit's distance from its record (:func:`_near_cell`); gap (h,) bool, the hit gathers by a walk of its
    own). Compiled (:mod:`core.native_kernels`) when the library is there."""
    lib = native_kernels.library()
    if lib is not None:
        return native_kernels.hit_cells(lib, caster, sources.hit_grid, triangle, barycentric, q, direction, distance,
                                        gap_tests(sources, n_record))
    return hit_cells_numpy(caster, sources, triangle, barycentric, q, direction, distance, n_record)


def gap_tests(sources, n_record: np.ndarray | None) -> tuple | None:
    """(n_record, gap_reach, GAP_COS, the corner's reach and height, or 0 and 0 without corner-gathering): the
    gap tests of :func:`hit_cells`; None without gap-gathering or record normals."""
    if not (sources.deviations.gap_gathering and n_record is not None):
        return None
    corner = sources.deviations.corner_gathering
    return (n_record, sources.gap_reach, GAP_COS, CORNER_REACH * sources.gap_reach if corner else 0.0,
            CORNER_HEIGHT * sources.gap_reach if corner else 0.0)


def hit_cells_numpy(caster, sources, triangle: np.ndarray, barycentric: np.ndarray, q: np.ndarray,
                    direction: np.ndarray, distance: np.ndarray, n_record: np.ndarray | None) -> tuple:
    """:func:`hit_cells` in numpy (the compiled kernel's reference)."""
    back, n_hit = side_met(caster.face_normals, triangle, direction)
    # deviation: hit-grid, docs/DEVIATIONS.md: the hit's grid cell (its E and mean albedo), if the
    # hit sees its centroid and the cell is small as the record sees it. A record 2 cm in front of a
    # wall (tracery, a pipe, a frame) gathers mostly from the wall patch right behind it, which a
    # cell's centroid in the open would light.
    E, centroid, rho, is_open = sources.hit_grid.lookup(triangle, barycentric, back)
    near = _near_cell(q, centroid, distance)
    gap = np.zeros(len(q), bool)
    if sources.deviations.gap_gathering and n_record is not None:  # deviation: gap-gathering
        # Not the grid, even where its cell is small: in a gap the cell's records spread the mouth's light.
        within = distance < sources.gap_reach
        gap = (near | within) & (dots(n_hit, n_record) < -GAP_COS)
        if sources.deviations.corner_gathering:  # deviation: corner-gathering, docs/DEVIATIONS.md
            # At the foot of a wall rising from the record's surface the records' zones, wider than the
            # corner, miss how the surface hides the wall's lower hemisphere.
            height = distance * dots(direction, n_record)
            gap |= (distance < CORNER_REACH * sources.gap_reach) & (height < CORNER_HEIGHT * sources.gap_reach)
    return n_hit, E, centroid, rho, is_open, near, gap


def gap_irradiance(scene, caster, sources, q: np.ndarray, n_hit: np.ndarray, rng: np.random.Generator
                   ) -> tuple[np.ndarray, int]:
    """(E_direct + E_indirect (h, 3), rays spent) at hits q facing n_hit (h, 3) that face the record
    they were gathered for from close by, or stand at a corner with its surface: E_indirect from a walk
    of their own (deviations: gap-gathering, corner-gathering).

    Such a hit lies in a gap between the record's surface and its own (the back of window tracery
    2 cm before a wall, a frame, a pipe): the record's surface covers much of the hit's hemisphere,
    which the records around the gap, out on the open wall with zones tens of centimetres wide, do
    not see: they lit the wall patch behind the cathedral's tracery at 2.2x a path tracer's. The walk
    leaves the hit by a cosine-weighted ray; each vertex y adds its albedo-weighted direct light
    (one shadow ray per light), and while y faces the vertex it came from (GAP_COS) from within
    ``sources.gap_reach`` (a R_min: the narrowest zone, the finest the records resolve) the walk
    bounces on from y, up to GAP_WALK_BOUNCES vertices: records spread a gap's light over their
    zones, so a record read inside a gap 1 cm deep in a 30 cm plate's shadow lit it from the plate's
    edges. Where the walk leaves the gap (or ends), y's records give its indirect light: they must
    see y, as a texel's do (deviation: record-visibility): y often lies on the gap's far side, under
    a slab or a box whose inside records lie a centimetre away on the same side. A y a R_min or more
    from the vertex before is out of the gap, an ordinary hit: it reads the hit grid's cell, as
    :func:`radiance_at_hits` does, when it sees the cell's centroid (:func:`_exits_on_grid`).
    """
    rays = 0
    rows, x, n_x = np.arange(len(q)), q, n_hit
    beta = np.ones((len(q), 3))  # the walk's throughput: albedos over survival probabilities
    vertices = []  # per bounce: (walk rows, y, n_y, beta at y, leaves the gap at y, y's triangle,
    #                  barycentric, the ray that met y, y's distance from the vertex before)
    for bounce in range(GAP_WALK_BOUNCES):
        d = cosine_directions(rng.random((len(x), 2)), n_x)
        origin = caster.offset_origins(x, n_x, d)
        hits = caster.intersect(origin, d, unit=True)
        rays += len(x)
        hit = np.flatnonzero(hits.hit)
        tri, bary = hits.triangle[hit], hits.barycentric[hit]
        _, n_y = side_met(caster.face_normals, tri, d[hit])
        y = origin[hit] + d[hit] * hits.t[hit, None]
        rho = albedo_at(scene, tri, bary).astype(np.float64)
        beta_y = beta[hit] * rho  # pi x the radiance leaving y, per cosine pdf
        inside = (hits.t[hit] < sources.gap_reach) & (dots(n_y, n_x[hit]) < -GAP_COS)
        inside &= bounce < GAP_WALK_BOUNCES - 1
        vertices.append((rows[hit], y, n_y, beta_y, ~inside, tri, bary, d[hit], hits.t[hit]))
        # Still in the gap: bounce on, or stop by Russian roulette on y's albedo (records read in a
        # gap spread the light of its mouth over their zones, so the walk does not end on them).
        walk = np.flatnonzero(inside)
        survive = np.clip(rho[walk].max(axis=1), GAP_WALK_SURVIVAL, 1.0)
        kept = rng.random(len(walk)) < survive
        walk, survive = walk[kept], survive[kept]
        rows, x, n_x, beta = rows[hit[walk]], y[walk], n_y[walk], beta_y[walk] / survive[:, None]
        if len(rows) == 0:
            break
    rows, y, n_y, beta_y, leaves, tri, bary, direction, t = (np.concatenate(v) for v in zip(*vertices))
    on_grid, E_grid, grid_rays = _exits_on_grid(caster, sources, y, n_y, leaves & (t >= sources.gap_reach), tri,
                                                bary, direction, t)
    rays += grid_rays
    E = np.zeros((len(q), 3))
    np.add.at(E, rows[on_grid], beta_y[on_grid] * E_grid)
    # The other vertices' direct light, and the records' light where the walk left the gap, in one batch each.
    own = np.ones(len(y), bool)
    own[on_grid] = False
    rows, y, n_y, beta_y, leaves = rows[own], y[own], n_y[own], beta_y[own], leaves[own]
    p, n = np.concatenate([q, y]), np.concatenate([n_hit, n_y])
    direct = gathering_direct(scene, caster, p, n, rng, sources.deviations.light_selection)
    rays += sum(direct.shadow_rays.values())
    E += direct.E[:len(q)]
    np.add.at(E, rows, beta_y * direct.E[len(q):])
    out = np.flatnonzero(leaves)
    if len(out):
        E_y, seen_rays = _indirect_seen(caster, sources, y[out], n_y[out])
        rays += seen_rays
        np.add.at(E, rows[out], beta_y[out] * E_y)
    return E, rays


def _exits_on_grid(caster, sources, y: np.ndarray, n_y: np.ndarray, far: np.ndarray, triangle: np.ndarray,
                   barycentric: np.ndarray, direction: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """(indices of the walk's vertices read from the hit grid, their cells' E_direct + E_indirect (g, 3),
    rays spent): the vertices ``far`` (v,) marks, where a walk left its gap a R_min or more from the
    vertex before, that see their grid cell's centroid and are not near it (HIT_GRID_NEAR x ``t`` (v,),
    their distance from that vertex), as :func:`radiance_at_hits` reads an ordinary gathering hit.
    Out of the gap such a vertex is one: a grid read and one ray instead of its shadow rays and the
    records' lookup (Sponza 16/m: corner-gathering's +7-17 % CPU became +-1 %). Walks run only with
    the hit grid (:func:`radiance_at_hits`). ``direction`` (v, 3): the rays that met the vertices."""
    candidate = np.flatnonzero(far)
    _, E, centroid, _, is_open, near, _ = hit_cells(caster, sources, triangle[candidate], barycentric[candidate],
                                                    y[candidate], direction[candidate], t[candidate], None)
    small = ~near
    candidate, E, centroid, is_open = candidate[small], E[small], centroid[small], is_open[small]
    ask = np.flatnonzero(~is_open)  # deviation: open-cells
    seen = is_open.copy()
    seen[ask] = caster.sides_visible(y[candidate[ask]], n_y[candidate[ask]], centroid[ask], n_y[candidate[ask]])
    return candidate[seen], E[seen], len(ask)


def _near_cell(q: np.ndarray, centroid: np.ndarray, distance: np.ndarray) -> np.ndarray:
    """(h,) bool: hits q (h, 3) nearer to where their ray left, ``distance`` (h,) away, than HIT_GRID_NEAR
    times their distance from their grid cell's ``centroid`` (h, 3): the cell would stand for much of
    that point's hemisphere, so the hit is shaded on its own."""
    offset = q - centroid
    return dots(offset, offset) > (HIT_GRID_NEAR * distance) ** 2


def seeing(sources, view):
    """``sources`` whose record lookup keeps only records that see the point (deviation:
    record-visibility, as a texel's lookup does; ``sources`` as they are with it off), casting on
    ``view`` (a :meth:`RayCaster.serial` view of the caller's own, which counts the rays). The copy
    shares the records' arrays and zone grid."""
    if not sources.deviations.record_visibility:
        return sources
    lookup = copy.copy(sources.lookup)
    lookup.caster = view
    return replace(sources, lookup=lookup)


def _irradiance_at_hits(scene, caster, sources, q: np.ndarray, n_hit: np.ndarray, rng: np.random.Generator
                        ) -> tuple[np.ndarray, int]:
    """(E_direct + E_indirect (h, 3), rays spent) at hits q facing n_hit (h, 3), each on its own."""
    E_indirect, seen_rays = _indirect_seen(caster, sources, q, n_hit)
    direct = gathering_direct(scene, caster, q, n_hit, rng, sources.deviations.light_selection)
    return direct.E + E_indirect, sum(direct.shadow_rays.values()) + seen_rays


def _indirect_seen(caster, sources, q: np.ndarray, n_hit: np.ndarray) -> tuple[np.ndarray, int]:
    """(:func:`indirect_at_hits` through :func:`seeing`, the rays that cast) at hits q facing n_hit (h, 3),
    on a view of ``caster`` of its own that counts the records' visibility rays and the fallback's."""
    view = caster.serial()
    E_indirect, _ = indirect_at_hits(view, seeing(sources, view), q, n_hit)
    return E_indirect, view.rays_cast


def indirect_at_hits(caster, sources, q: np.ndarray, n_hit: np.ndarray) -> tuple[np.ndarray, int]:
    """(E_indirect (h, 3), fallback rays) at hits facing n_hit (h, 3): pass 2's records, else the nearest photon.

    The hits are looked up in Morton order (:func:`~core.zone_grid.spatial_order`): the record grid
    and the photon kd-tree are then walked along neighbouring cells and nodes.
    """
    (E_indirect,), hole_rays, _ = _indirect_facing(caster, sources, q, (n_hit,))
    return E_indirect, hole_rays


def indirect_on_both_sides(caster, sources, q: np.ndarray, n: np.ndarray, known: np.ndarray | None = None
                           ) -> tuple[np.ndarray, np.ndarray, int, np.ndarray]:
    """:func:`indirect_at_hits` at points q on the side n (h, 3) faces and on the other: (E front (h, 3),
    E back (h, 3), fallback rays, picks (2, h)). The nearest-photon fallback asks the kd-tree once per point.

    picks : per side and point the fallback's photon (:func:`~core.photon_fallback.nearest_photon_seen`;
    NOT_ASKED where a record accepted the point); known : such picks from an earlier lookup at the
    same points, reused where they were asked (a pick depends on the point alone).
    """
    (front, back), rays, picks = _indirect_facing(caster, sources, q, (n, -n), known)
    return front, back, rays, picks


def _indirect_facing(caster, sources, q: np.ndarray, normals: tuple, known: np.ndarray | None = None
                     ) -> tuple[tuple, int, np.ndarray]:
    """((E_indirect (h, 3) facing each of ``normals``, ...), fallback rays, picks (sides, h)) at points
    q (h, 3); the sides share one Morton order and one set of kd-tree answers. known : as
    :func:`indirect_on_both_sides`."""
    order = spatial_order(q)
    q = q[order]
    neighbours = NearestPhotons(sources.density, q)
    # The records a point may take depend on where it is, not on the side it faces: one search for all sides.
    pairs = sources.lookup.candidates(q) if len(normals) > 1 else None
    out, hole_rays = [], 0
    picks = np.full((len(normals), len(q)), NOT_ASKED, np.int64)
    for side, n_hit in enumerate(normals):
        n_hit = n_hit[order]
        E_sorted, w_sum = sources.lookup.irradiance(q, n_hit, pairs)
        hole = np.flatnonzero(w_sum <= 0)
        pick = np.full(len(hole), NOT_ASKED, np.int64) if known is None else known[side, order[hole]]
        if len(hole) and sources.nearest_photon_fallback:
            ask = np.flatnonzero(pick == NOT_ASKED)
            if len(ask):
                pick[ask], rays = nearest_photon_seen(caster, sources.density, q[hole[ask]], n_hit[hole[ask]],
                                                      neighbours, hole[ask])
                hole_rays += rays
            E_sorted[hole] = lent_irradiance(sources.density, sources.lighting, pick, q[hole],
                                             sources.deviations.fallback_empty_disc)
            picks[side, order[hole]] = pick
        E_indirect = np.empty_like(E_sorted)
        E_indirect[order] = E_sorted
        out.append(E_indirect)
    return tuple(out), hole_rays, picks
