"""Record walls: where a zone of influence ends at a wall standing on its surface.

deviation: wall-sectors, docs/DEVIATIONS.md (switch ``Deviations.wall_sectors``).

A zone of influence is a sphere: where a wall stands on the surface (a 1 mm partition on a
floor, a box resting on it), the sphere reaches the floor on the wall's far side, same plane,
same normal, and Ward's weights carry light through. Each record casts one ray per azimuth
sector of its tangent plane (:func:`wall_distances`); points past the star polygon through the
hits (:func:`beyond_wall`) are not the record's.
"""
from __future__ import annotations

import numpy as np

from .constants import FAR_WALL, SECTOR_OFFSET, TINY_WALL, WALL_LIFT, WALL_MARGIN, WALL_RAYS
from .sampling import orthonormal_basis


def open_walls(count: int) -> np.ndarray:
    """(count, WALL_RAYS) float32 of inf: no wall known in any sector."""
    return np.full((count, WALL_RAYS), np.inf, np.float32)


def _ray_angle(i) -> np.ndarray:
    """Tangent-plane angle of wall ray ``i`` (0..WALL_RAYS-1), from t1 of the record's frame."""
    return SECTOR_OFFSET + 2 * np.pi * (np.asarray(i) + 0.5) / WALL_RAYS


def sector_directions() -> tuple[np.ndarray, np.ndarray]:
    """(cos, sin) (WALL_RAYS,) of the sector rays' angles (:func:`_ray_angle`), as :class:`_Sector` computes them."""
    angle = _ray_angle(np.arange(WALL_RAYS))
    return np.cos(angle), np.sin(angle)


def wall_distances(caster, p_k: np.ndarray, n_k: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """(K, WALL_RAYS) float32 distance to the nearest wall per sector of each record's tangent plane.

    One ray per sector, along the tangent plane at the sector's centre angle and lifted by
    :data:`~core.constants.WALL_LIFT` of the reach, finds walls up to ``reach`` (K,);
    inf where none is within reach.
    """
    K = len(p_k)
    phi = _ray_angle(np.arange(WALL_RAYS))
    t1, t2 = orthonormal_basis(n_k)
    d = (np.cos(phi)[None, :, None] * t1[:, None] + np.sin(phi)[None, :, None] * t2[:, None]).reshape(-1, 3)
    origin = np.repeat(p_k + (WALL_LIFT * reach)[:, None] * n_k, WALL_RAYS, axis=0)
    t_max = np.repeat(reach, WALL_RAYS)
    t = caster.intersect(origin, d, t_max=t_max).t
    # A lifted origin lying on another surface (a record where a railing bar meets the rail it
    # holds) hits that surface at t = 0 in every direction; walls at 0 would leave the record no
    # disc at all. Look again from just past that surface.
    start = np.flatnonzero(t <= caster.epsilon)
    if len(start):
        step = caster.epsilon
        t[start] = step + caster.intersect(origin[start] + step * d[start], d[start], t_max=t_max[start] - step).t
    return t.reshape(K, WALL_RAYS).astype(np.float32)


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
    joining their hits. The segment follows a straight wall whatever its angle to the rays, so
    directions parallel to a wall keep their reach, and nothing behind a wall slips between two
    rays that both met it. A ray that met nothing stands in with a far point (the wall bends
    away). That leaves a wedge between a wall met by one ray only and its far segment, through
    which a floor running on under the wall reaches its far side: Equation 3 asks
    :func:`beyond_wall_and_reach` instead and casts a ray in the wedge
    (:class:`core.interpolation.CacheLookup`).
    """
    sector = _Sector(wall, delta, n_k)
    return sector.beyond(sector.far())


def beyond_wall_and_reach(wall: np.ndarray, delta: np.ndarray, n_k: np.ndarray, reach: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
    """((m,) bool past the polygon whose missed rays stand in at ``reach`` (m,), how far the rays
    looked (:func:`wall_distances`), (m,) bool :func:`beyond_wall`), from one sector lookup.

    A straight wall through a missed ray's neighbour's hit crosses it no nearer than ``reach``, so
    the first polygon has no wedge; it also leaves out the open floor beside a column, which the
    far point keeps."""
    sector = _Sector(wall, delta, n_k)
    return sector.beyond(np.asarray(reach, np.float64)), sector.beyond(sector.far())


class _Sector:
    """The two sector rays around each offset (m,): the point in the record's tangent frame and the
    rays' hit distances (inf: the ray met nothing)."""

    def __init__(self, wall: np.ndarray, delta: np.ndarray, n_k: np.ndarray):
        t1, t2 = orthonormal_basis(n_k)
        self.x = np.einsum("ij,ij->i", delta, t1)
        self.y = np.einsum("ij,ij->i", delta, t2)
        turn = np.mod((np.arctan2(self.y, self.x) - SECTOR_OFFSET) / (2 * np.pi), 1.0) * WALL_RAYS - 0.5
        self.i = np.floor(turn).astype(np.int64) % WALL_RAYS  # the ray just before the point's direction
        self.j = (self.i + 1) % WALL_RAYS
        rows = np.arange(len(delta))
        self.t_i, self.t_j = wall[rows, self.i].astype(np.float64), wall[rows, self.j].astype(np.float64)
        self.finite = np.isfinite(self.t_i) | np.isfinite(self.t_j)

    def far(self) -> np.ndarray:
        """(m,) the far stand-in for a ray that met nothing: FAR_WALL x its neighbour's hit."""
        return FAR_WALL * np.where(np.isfinite(self.t_i), self.t_i, np.where(np.isfinite(self.t_j), self.t_j, 1.0))

    def beyond(self, far: np.ndarray) -> np.ndarray:
        """(m,) bool: past the segment between the two rays' hits, ``far`` (m,) standing in for a miss."""
        # A wall at distance 0 would make its segment a point through the record, on whose line every
        # point lies: nothing would be past it while the kernel mass it leaves is ~0. A tiny positive
        # distance keeps the polygon a polygon.
        t_i = np.maximum(np.where(np.isfinite(self.t_i), self.t_i, far) * (1.0 - WALL_MARGIN), TINY_WALL)
        t_j = np.maximum(np.where(np.isfinite(self.t_j), self.t_j, far) * (1.0 - WALL_MARGIN), TINY_WALL)
        a_i, a_j = _ray_angle(self.i), _ray_angle(self.j)
        hx_i, hy_i = t_i * np.cos(a_i), t_i * np.sin(a_i)
        hx_j, hy_j = t_j * np.cos(a_j), t_j * np.sin(a_j)
        ex, ey = hx_j - hx_i, hy_j - hy_i
        # The origin and the point on opposite sides of the segment's line: the point is past the wall.
        side_point = ex * (self.y - hy_i) - ey * (self.x - hx_i)
        side_origin = ex * (0.0 - hy_i) - ey * (0.0 - hx_i)
        return self.finite & (side_point * side_origin < 0)


def past_walls(wall: np.ndarray, delta: np.ndarray, n_k: np.ndarray) -> np.ndarray:
    """(m,) bool: :func:`beyond_wall` for m offsets from ONE record (wall (S,), n_k (3,))."""
    m = len(delta)
    return beyond_wall(np.broadcast_to(wall, (m, WALL_RAYS)), delta, np.broadcast_to(n_k, (m, 3)))


def has_walls(wall: np.ndarray | None) -> bool:
    """True when ``wall`` knows of at least one wall."""
    return wall is not None and bool(np.isfinite(wall).any())
