"""Texels a triangle edge crosses are sampled on the triangle under their centre (deviation: crease-folding).

docs/DEVIATIONS.md, switch ``Deviations.crease_folding``. Cycles bakes a texel on the triangle under its
centre: the sub-pixel jitter of its bake samples stays on that triangle, whatever lies across the edge.
Where a crease crosses a texel (a column's facets narrower than a texel, a chamfer, a moulding's step) the
texel holds the light of its centre's face alone: PDIC's regular samples, on whichever triangle is under
them, averaged two faces, and the cathedral's faceted column shafts, lit on one facet and dark on the next,
came out at twice Cycles' light. Across an edge between coplanar triangles the texel's footprint is still
cut to the centre's side, and its samples' mean lies off the texel centre: where the light changes fast
(near a lamp, at a shadow's edge) Cycles bakes the light of that cut square, not of the whole one.

A texel with a sample on another triangle than its centre's takes the samples
:func:`core.raster.centre_footprints` places on the centre triangle instead of its own. Texels whose centre
lies on no triangle keep their samples: Cycles does not bake them. The jittered points over a texel's
footprint that the direct light and texel validity take at edges (:func:`core.texels.footprint_texel_points`)
drop those off the centre triangle.
"""
from __future__ import annotations

import numpy as np


def off_centre_triangle(texel: np.ndarray, triangle: np.ndarray, centre_triangle: np.ndarray) -> np.ndarray:
    """(s,) bool: samples on another triangle than the one under their texel's centre.

    texel, triangle : (s,) the samples' flat texel and triangle; centre_triangle : (width * height,) the
    triangle under each texel's centre, -1 none.
    """
    centre = centre_triangle[texel]
    return (centre >= 0) & (centre != triangle)


def straddling_texels(texel: np.ndarray, triangle: np.ndarray, centre_triangle: np.ndarray) -> np.ndarray:
    """(k,) the texels with a sample off their centre triangle (:func:`off_centre_triangle`), unique, ascending."""
    return np.unique(texel[off_centre_triangle(texel, triangle, centre_triangle)])
