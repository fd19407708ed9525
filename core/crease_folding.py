"""Texel samples across a crease fold onto the triangle under the texel's centre (deviation: crease-folding).

docs/DEVIATIONS.md, switch ``Deviations.crease_folding``. Cycles bakes a texel on the triangle under
its centre: the sub-pixel jitter of its bake samples is folded back into that triangle, as a
mirrored texture repeats (``bake_clamp_mirror_repeat`` in its bake kernel). Where a crease crosses a
texel (a column's facets narrower than a texel, a chamfer, a moulding's step) the texel holds the
light of its centre's face alone. PDIC's regular samples lie on whichever triangle is under them, so
such a texel averaged two faces: the cathedral's faceted column shafts, lit on one facet and dark on
the next, came out at twice Cycles' light there (0.019 against 0.0097 E/pi) although a path tracer
at PDIC's own samples agreed with PDIC.

A sample on a triangle whose geometric normal turns more than CREASE_FOLD_ANGLE from the centre
triangle's moves onto the centre triangle, to where Cycles' fold puts it; samples on a coplanar or
gently curving neighbour stay where they are (there the two conventions light the same surface).
Texels whose centre lies on no triangle keep their samples: Cycles does not bake them.
"""
from __future__ import annotations

import numpy as np

from .constants import CREASE_FOLD_ANGLE
from .raster import TexelSamples, barycentric_weights, twice_area


def mirror(x: np.ndarray, limit: np.ndarray | float) -> np.ndarray:
    """x folded into [0, limit] as a mirrored texture repeats (Cycles' ``bake_clamp_mirror_repeat``)."""
    limit = np.maximum(limit, 1e-12)
    scaled = x / limit
    whole = np.floor(scaled)
    frac = scaled - whole
    return np.where(whole.astype(np.int64) & 1, 1.0 - frac, frac) * limit


def fold_across_creases(samples: TexelSamples, uv: np.ndarray, normals: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, int]:
    """(triangle (s,), barycentric (s, 3), samples folded) of ``samples`` with the ones across a crease
    from their texel's centre triangle folded onto it.

    uv : (t, 3, 2) the rasterised UV triangles (``samples.triangle`` indexes them);
    normals : (t, 3) their unit geometric normals.
    The fold mirrors the sample's corner weights 0 and 1 into [0, 1] and [0, 1 - w0]: Cycles folds
    Blender's barycentric (u, v), the weights of corners 0 and 1, before turning them into its own.
    """
    tri, bary = samples.triangle, samples.barycentric
    centre = samples.centre_triangle.reshape(-1)[samples.texel]
    on_face = centre >= 0
    turn = np.einsum("ij,ij->i", normals[tri], normals[np.maximum(centre, 0)])
    fold = np.flatnonzero(on_face & (centre != tri) & (turn < np.cos(np.radians(CREASE_FOLD_ANGLE))))
    if len(fold) == 0:
        return tri, bary, 0
    size = [samples.width, samples.height]
    position = np.einsum("sk,skd->sd", bary[fold], np.asarray(uv, np.float64)[tri[fold]] * size)
    corners = np.asarray(uv, np.float64)[centre[fold]] * size
    w0, w1, _ = barycentric_weights(corners, position[:, 0], position[:, 1], twice_area(corners))
    w0 = mirror(w0, 1.0)
    w1 = mirror(w1, 1.0 - w0)
    tri, bary = tri.copy(), bary.copy()
    tri[fold] = centre[fold]
    bary[fold] = np.stack([w0, w1, 1.0 - w0 - w1], axis=1)
    return tri, bary, len(fold)
