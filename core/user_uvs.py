"""Light-map UVs the user laid out: checked as an unwrap's are, and a map size for them.

Game pipelines often carry a light-map UV map of their own (a second UV channel made in Blender or
a DCC tool, referenced by the engine), and xatlas cannot chart every mesh. An object may name such
a UV map instead of being unwrapped; PDIC bakes into that layout as it is (copied into
``PDIC_Lightmap``, the user's map untouched). A layout the bake cannot use is refused with the reason,
never baked wrong: corners outside the 0-1 square (no texel holds them) and texel centres inside two
or more UV triangles (mirrored or stacked islands would share texels: one surface's light on the
other) are errors, as they are for an unwrap (:func:`core.unwrap.unwrap`'s gate).

UVs follow Blender: u to the right, v up, in [0, 1].
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .unwrap import uv_areas
from .uv_overlap import uv_overlaps

OUTSIDE_TOLERANCE = 1e-6
"""UV units a corner may lie outside [0, 1] (float32 rounding of a layout packed to the border)."""
UNEVEN_DENSITY = 0.8
"""A layout whose surface gets, at its area-weighted median, under this fraction of the Texel Density
asked has islands not scaled to their surface (Blender's Lightmap Pack gives Sponza's large faces a median
5.65 texels/m in a map sized for 8 on average; over the camera pixels away from its islands' edges,
mostly on those faces, its error is 4.2 % against 3.2 % in PDIC's uniform unwrap, bench/README.md): the
bake says so."""


class UserUVError(ValueError):
    """The UV map cannot hold a light map; the message says why and what to do."""


@dataclass(frozen=True)
class UserUVLayout:
    """A user's light-map layout, checked.

    uv : (t, 3, 2) float32 per-triangle-corner UVs in [0, 1].
    resolution : light-map width (= height), texels.
    utilization : fraction of the map covered by UV triangles (0..1).
    unmapped_area : fraction of the mesh's surface area on triangles with no UV area (they get no
        texels of their own; 0 for a full layout).
    density_median : texels per scene unit at the area-weighted median of the triangles'
        (:func:`texel_densities`): what most of the surface gets.
    """

    uv: np.ndarray
    resolution: int
    utilization: float
    unmapped_area: float
    density_median: float = 0.0


def resolution_for(uv_area: float, surface_area: float, texel_density: float, default_resolution: int,
                   min_resolution: int, max_resolution: int) -> int:
    """Map width (= height) that gives the layout ``texel_density`` texels per scene unit.

    uv_area : fraction of the map the UV triangles cover (0..1]; surface_area : the mesh's world
    area, scene units squared; texel_density : texels per unit (0: ``default_resolution``).
    The layout is kept as it is, so the size alone sets the density: resolution^2 x uv_area texels
    over surface_area, i.e. texel_density x sqrt(surface_area / uv_area), rounded up to a multiple
    of 4 (block-compressed formats) and clamped to [min_resolution, max_resolution].
    """
    if texel_density == 0:
        return int(default_resolution)
    if not (uv_area > 0 and surface_area > 0 and math.isfinite(surface_area) and texel_density > 0):
        raise ValueError(f"resolution_for: UV area {uv_area!r}, surface area {surface_area!r}, "
                         f"texel density {texel_density!r}")
    texels = math.ceil(texel_density * math.sqrt(surface_area / uv_area))
    return int(min(max(4 * math.ceil(texels / 4), min_resolution), max_resolution))


def check_layout(uv: np.ndarray, triangle_area: np.ndarray, resolution: int, where: str) -> UserUVLayout:
    """The layout ``uv`` (t, 3, 2) at ``resolution``, or :class:`UserUVError` saying why it cannot hold a
    light map. ``triangle_area`` (t,) are the triangles' world areas; ``where`` names the object and
    UV map in messages (e.g. "UV map 'UV2' of object 'Wall'")."""
    uv = np.ascontiguousarray(uv, np.float32)
    if uv.ndim != 3 or uv.shape[1:] != (3, 2) or len(uv) != len(triangle_area):
        raise ValueError(f"check_layout: UVs of shape {uv.shape} for {len(triangle_area)} triangles")
    if not np.isfinite(uv).all():
        raise UserUVError(f"{where}: {int((~np.isfinite(uv)).any(axis=(1, 2)).sum())} triangles have "
                          f"non-finite UVs (NaN or inf)")
    outside = ((uv < -OUTSIDE_TOLERANCE) | (uv > 1 + OUTSIDE_TOLERANCE)).any(axis=(1, 2))
    if outside.any():
        raise UserUVError(f"{where}: {int(outside.sum())} of its {len(uv)} triangles lie partly outside the "
                          f"0-1 UV square, where a light map has no texels; scale the islands into it "
                          f"(UV > Pack Islands), or clear the object's Light-Map UVs to let PDIC unwrap")
    area_uv = uv_areas(uv)
    if not area_uv.sum() > 0:
        raise UserUVError(f"{where}: its UV triangles have no area (every corner at one point or on a line)")
    overlaps = uv_overlaps(uv, None, resolution, resolution)
    if overlaps:
        raise UserUVError(f"{where}: {overlaps} texel centres of the {resolution}x{resolution} light map lie "
                          f"inside two or more of its UV triangles (overlapping, mirrored or stacked islands "
                          f"would share texels and each other's light); lay the islands out apart, or clear "
                          f"the object's Light-Map UVs to let PDIC unwrap")
    world = np.asarray(triangle_area, np.float64)
    unmapped = float(world[area_uv == 0].sum() / world.sum()) if world.sum() > 0 else 0.0
    density = texel_densities(area_uv, world, resolution)
    return UserUVLayout(uv, int(resolution), float(min(area_uv.sum(), 1.0)), unmapped,
                        area_weighted_median(density, world))


def texel_densities(uv_area: np.ndarray, triangle_area: np.ndarray, resolution: int) -> np.ndarray:
    """(t,) texels per scene unit on each triangle: sqrt(its texels / its world area); 0 without world area.
    uv_area : (t,) UV areas in units of the map (:func:`core.unwrap.uv_areas`); triangle_area : (t,) scene units^2."""
    texels = np.asarray(uv_area, np.float64) * float(resolution) ** 2
    world = np.asarray(triangle_area, np.float64)
    return np.sqrt(np.divide(texels, world, out=np.zeros_like(world), where=world > 0))


def area_weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The value at which half of the total weight lies below (0 for no weight)."""
    order = np.argsort(values, kind="stable")
    cumulative = np.cumsum(np.asarray(weights, np.float64)[order])
    if len(cumulative) == 0 or not cumulative[-1] > 0:
        return 0.0
    return float(np.asarray(values)[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])
