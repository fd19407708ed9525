"""Light portals: windows a sun's and the world's photons are sent through (deviation: portal-photons).

docs/DEVIATIONS.md, switch ``Deviations.portal_photons``. A sun and the world emit their photons along lines
from a disc around the scene's bounding sphere (:mod:`core.lights`); in a room lit through a window few of
them enter (the daylight room of bench/daylight_room.py: about 3 % of 1 M), and the room's second bounce
rests on those few. Cycles users mark such windows with light portals (area lights with *Portal* on). Here a
share PORTAL_SHARE of each such emitter's photons take lines through the portals instead: a point on a
portal and a direction (cosine-weighted about the portal's inward normal for the world, the sun's own for a
sun), the line then traced from the disc like any other. Every photon's power is its emitter's flux over
the photons, divided by the mixture's density relative to the disc's alone (one-sample mixture, balance
weights: ``alpha + (1 - alpha) p_portal / p_disc``), so the light is the same in expectation whatever the
portals, and a line the portal strategy could not draw keeps its disc weight. Only lines and weights change:
what the photons meet (an overhang outside the window, glass in it) is traced as before.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .constants import PORTAL_SHARE
from .sampling import concentric_disk

ROUND = ("DISK", "ELLIPSE")
ON_SPHERE = 1e-6
"""Relative slack of :meth:`Portals.usable`'s sphere test: a corner at a vertex of the scene's bounding box is on
the sphere up to rounding, and Blender's float32 ``matrix_world`` puts such a portal's corners 0.9-1.3e-8 of the
radius past it (a whole-wall portal turned by pi/2: cos(pi/2) is -4.4e-8 in float32)."""


@dataclass(frozen=True)
class Portals:
    """The scene's portals inside its bounding sphere, as arrays: centre, normal (inward: the side a Blender
    area light emits toward), axis_u, axis_v (P, 3); half_u, half_v, area (P,); round (P,) bool."""

    centre: np.ndarray
    normal: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    half_u: np.ndarray
    half_v: np.ndarray
    area: np.ndarray
    round: np.ndarray

    @staticmethod
    def usable(portal, sphere_centre: np.ndarray, radius: float) -> bool:
        """Whether the photons can be sent through ``portal`` (an area-light shape): it has area and its corners
        lie inside the bounding sphere, or on it up to ON_SPHERE (a line through a point outside it may miss
        the disc the photons start from; one through a point on it, along the disc's axis (the world's lines,
        a sun of no angle), lands on the disc's rim; a sun's cone of half-angle h can start such a line up to
        about 2 R sin h past the rim, whose weight still counts the disc's density: negligible for the
        sun's fraction of a degree). A portal filling a whole outer wall of a box has its corners on the
        sphere."""
        c, u, v = (np.asarray(x, np.float64) for x in (portal.position, portal.axis_u, portal.axis_v))
        half = np.array([[su * portal.size_u, sv * portal.size_v] for su in (-0.5, 0.5) for sv in (-0.5, 0.5)])
        corners = c + half @ np.stack([u, v])
        reach = np.linalg.norm(corners - sphere_centre, axis=1)
        return portal.area > 0 and bool(np.all(reach <= radius * (1.0 + ON_SPHERE)))

    @staticmethod
    def of(scene, sphere_centre: np.ndarray, radius: float) -> "Portals | None":
        """The portals of ``scene`` (``Scene.portals``: area-light shapes) the photons can use (:meth:`usable`),
        or None."""
        keep = [p for p in scene.portals if Portals.usable(p, sphere_centre, radius)]
        if not keep:
            return None
        arrays = [np.array([np.asarray(getattr(p, f), np.float64) for p in keep]) for f in ("position", "normal",
                                                                                          "axis_u", "axis_v")]
        return Portals(*arrays, np.array([0.5 * p.size_u for p in keep]), np.array([0.5 * p.size_v for p in keep]),
                       np.array([p.area for p in keep]), np.array([p.shape in ROUND for p in keep]))

    def __len__(self) -> int:
        return len(self.area)

    def sample(self, j: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(m, 3) points uniform on portals ``j`` (m,)."""
        square = rng.random((len(j), 2)) * 2.0 - 1.0
        disc = concentric_disk(rng.random((len(j), 2)))[0]
        uv = np.where(self.round[j, None], disc, square)
        return (self.centre[j] + uv[:, :1] * self.half_u[j, None] * self.axis_u[j]
                + uv[:, 1:2] * self.half_v[j, None] * self.axis_v[j])

    def pick(self, m: int, chance: np.ndarray, rng: np.random.Generator
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows (k,): the PORTAL_SHARE of ``m`` lines drawn through the portals, their portals (k,) chosen by
        ``chance`` (P,), a point on each (k, 3))."""
        rows = np.flatnonzero(rng.random(m) < PORTAL_SHARE)
        j = rng.choice(len(self), len(rows), p=chance)
        return rows, j, self.sample(j, rng)

    def crossed(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """((m, P) bool: line o + t d (any t) crosses portal j, (m, P) cos of d to its normal) for lines
        o, d (m, 3), d unit."""
        cos = d @ self.normal.T
        safe = np.where(np.abs(cos) > 1e-12, cos, 1.0)
        t = np.einsum("pk,mpk->mp", self.normal, self.centre[None] - o[:, None]) / safe
        x = o[:, None] + t[..., None] * d[:, None] - self.centre[None]
        a = np.einsum("mpk,pk->mp", x, self.axis_u) / self.half_u
        b = np.einsum("mpk,pk->mp", x, self.axis_v) / self.half_v
        inside = np.where(self.round, a * a + b * b <= 1.0, (np.abs(a) <= 1.0) & (np.abs(b) <= 1.0))
        return inside & (np.abs(cos) > 1e-12), cos


def through_portals(o: np.ndarray, d: np.ndarray, portal_rows: np.ndarray, x: np.ndarray, centre: np.ndarray,
                    reach: float, facing: np.ndarray | None = None) -> None:
    """Move the origins of rows ``portal_rows`` onto the plane of the disc the emitter starts from, in place: the
    point of the line through x (k, 3) along d that lies ``reach`` before the sphere's centre along ``facing``
    (3,) (a sun's disc, across its axis), or along the line itself (None: the world's disc, across each d)."""
    dk = d[portal_rows]
    if facing is None:
        back = np.einsum("ij,ij->i", x - centre, dk) + reach
    else:
        back = ((x - centre) @ facing + reach) / (dk @ facing)
    o[portal_rows] = x - dk * back[:, None]


def mixture_power(flux_each: np.ndarray, ratio: np.ndarray, share: float = PORTAL_SHARE) -> np.ndarray:
    """(m, 3) photon powers: ``flux_each`` (m, 3) (flux / photons) over alpha + (1 - alpha) ratio, alpha the
    disc's share and ratio (m,) each line's portal density over its disc density."""
    return flux_each / ((1.0 - share) + share * ratio)[:, None]
