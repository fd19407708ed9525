"""Texels a crease crosses are sampled on the triangle under their centre (deviation: crease-folding).

docs/DEVIATIONS.md, switch ``Deviations.crease_folding``. Cycles bakes a texel on the triangle under its
centre: the sub-pixel jitter of its bake samples stays on that triangle. Where a crease crosses a texel
(a column's facets narrower than a texel, a chamfer, a moulding's step) the texel holds the light of its
centre's face alone. PDIC's regular samples lie on whichever triangle is under them, so such a texel
averaged two faces: the cathedral's faceted column shafts, lit on one facet and dark on the next, came
out at twice Cycles' light there (0.019 against 0.0097 E/pi) although a path tracer at PDIC's own
samples agreed with PDIC.

A texel with a sample on a triangle whose geometric normal turns more than CREASE_FOLD_ANGLE from the
centre triangle's takes the samples :func:`core.raster.centre_footprints` places on the centre triangle
instead of its own; texels whose samples lie on coplanar or gently curving neighbours keep them (there
the two conventions light the same surface). Texels whose centre lies on no triangle keep their
samples: Cycles does not bake them. The jittered points over a texel's footprint that the direct light
and texel validity take at edges (:func:`core.texels.footprint_texel_points`) drop those across a crease.
"""
from __future__ import annotations

import numpy as np

from .constants import CREASE_FOLD_ANGLE


def across_creases(texel: np.ndarray, triangle: np.ndarray, centre_triangle: np.ndarray, normals: np.ndarray
                   ) -> np.ndarray:
    """(s,) bool: samples on a triangle turned more than CREASE_FOLD_ANGLE from their texel's centre triangle.

    texel, triangle : (s,) the samples' flat texel and triangle (indexing ``normals``); centre_triangle :
    (width * height,) the triangle under each texel's centre, -1 none; normals : (t, 3) unit geometric normals.
    """
    centre = centre_triangle[texel]
    turn = np.einsum("ij,ij->i", normals[triangle], normals[np.maximum(centre, 0)])
    return (centre >= 0) & (centre != triangle) & (turn < np.cos(np.radians(CREASE_FOLD_ANGLE)))


def crease_texels(texel: np.ndarray, triangle: np.ndarray, centre_triangle: np.ndarray, normals: np.ndarray
                  ) -> np.ndarray:
    """(k,) the texels with a sample across a crease (:func:`across_creases`), unique, ascending."""
    return np.unique(texel[across_creases(texel, triangle, centre_triangle, normals)])
