"""Texel samples across a crease fold onto the triangle under the texel's centre (deviation: crease-folding).

docs/DEVIATIONS.md, switch ``Deviations.crease_folding``. Cycles bakes a texel on the triangle under
its centre: the sub-pixel jitter of its bake samples is folded back into that triangle, as a
mirrored texture repeats (``bake_clamp_mirror_repeat`` in its bake kernel; :func:`core.raster.fold_into`).
Where a crease crosses a texel (a column's facets narrower than a texel, a chamfer, a moulding's step)
the texel holds the light of its centre's face alone. PDIC's regular samples lie on whichever triangle is under them, so
such a texel averaged two faces: the cathedral's faceted column shafts, lit on one facet and dark on
the next, came out at twice Cycles' light there (0.019 against 0.0097 E/pi) although a path tracer
at PDIC's own samples agreed with PDIC.

A sample on a triangle whose geometric normal turns more than CREASE_FOLD_ANGLE from the centre
triangle's moves onto the centre triangle, to where Cycles' fold puts it; samples on a coplanar or
gently curving neighbour stay where they are (there the two conventions light the same surface).
Texels whose centre lies on no triangle keep their samples: Cycles does not bake them. The regular
samples fold (:func:`core.texels.lift_texels`), and so do the jittered points over a texel's footprint
that the direct light and texel validity take at edges (:func:`core.texels.footprint_texel_points`).
"""
from __future__ import annotations

import numpy as np

from .constants import CREASE_FOLD_ANGLE
from .raster import fold_into


def fold_across_creases(texel: np.ndarray, triangle: np.ndarray, bary: np.ndarray, centre_triangle: np.ndarray,
                        uv: np.ndarray, normals: np.ndarray, width: int, height: int
                        ) -> tuple[np.ndarray, np.ndarray, int]:
    """(triangle (s,), barycentric (s, 3), samples folded): the samples with the ones across a crease from
    their texel's centre triangle folded onto it.

    texel, triangle, bary : (s,), (s,), (s, 3) the samples' flat texel, triangle (indexing ``uv``) and
    corner weights; centre_triangle : (width * height,) the triangle under each texel's centre, -1 none;
    uv : (t, 3, 2) the rasterised UV triangles; normals : (t, 3) their unit geometric normals.
    The fold is Cycles' (:func:`core.raster.fold_into`).
    """
    centre = centre_triangle[texel]
    turn = np.einsum("ij,ij->i", normals[triangle], normals[np.maximum(centre, 0)])
    fold = np.flatnonzero((centre >= 0) & (centre != triangle) & (turn < np.cos(np.radians(CREASE_FOLD_ANGLE))))
    if len(fold) == 0:
        return triangle, bary, 0
    uv = np.asarray(uv, np.float64) * [width, height]
    position = np.einsum("sk,skd->sd", bary[fold], uv[triangle[fold]])
    triangle, bary = triangle.copy(), bary.copy()
    triangle[fold] = centre[fold]
    bary[fold] = fold_into(uv[centre[fold]], position[:, 0], position[:, 1])
    return triangle, bary, len(fold)
