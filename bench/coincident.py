"""Texel samples on coincident faces: another triangle passes through the sample's point.

Where two triangles overlap in one plane (a mesh's duplicated faces, or two parts glued face to
face), Cycles' bake is not a reference: its rays leave a surface point with no offset, skip only
their own triangle and hit the coincident one at distance ~0, so the texel bakes black. On Sponza
(16 texels/m) 235 interior texels bake to exactly 0 in both reference seeds where PDIC has light,
on vault and arch faces duplicated in place (mesh triangles 24315-24316 over 24400, ...); there the
path referee (bench/path_referee.py) traces 1.37 and 1.36, PDIC 1.37 and 1.36. PDIC's rays leave
``RayCaster.epsilon`` above the surface, past such a duplicate, which is what a light map wants: a
renderer shows either face with the light of the room it faces. Comparisons against Cycles leave
out the texels with a sample on such a face (``bench.run.interior_texels``), and count them:
Sponza 2,750 of 889,291 interior texels (PDIC Final's indirect error per texel / 8x8 blocks 8.37 /
8.61 % -> 7.49 / 6.46 %), the cathedral 6,803 of 81,374 (its stacked mouldings and stairs; 23.55 /
22.17 % -> 17.90 / 16.86 %, mean 1.041 -> 1.029 of Cycles), the Cornell box and the occluded
building none.

The test casts, from COINCIDENT_EPSILONS epsilons above each sample, a ray back through it over
twice that distance against the triangles of the other half of a random split of the mesh: a hit
is a triangle (either facing) within that distance of the plane at the sample. A coincident pair
falls in different halves with probability 1/2 per split; SPLITS splits miss it with 2^-SPLITS.
"""
from __future__ import annotations

import numpy as np

COINCIDENT_EPSILONS = 2.0
"""How near another triangle must pass to the sample, in ``RayCaster.epsilon`` (PDIC's ray-origin
offset; a layer farther away is a real occluder to both bakers)."""
EDGE_MARGIN = 1e-3
"""Least barycentric coordinate of the hit in the other triangle (its edges are shared, not overlaps)."""
SPLITS = 8
"""Random halvings of the mesh; a coincident pair escapes all of them with probability 2^-8."""


def coincident_samples(positions: np.ndarray, p: np.ndarray, n: np.ndarray, triangle: np.ndarray,
                       seed: int = 0) -> np.ndarray:
    """(m,) bool: samples p (m, 3) on ``triangle`` (m,) facing their face normal n (m, 3) through
    which another triangle of ``positions`` (T, 3, 3) passes (within COINCIDENT_EPSILONS epsilons)."""
    from pdic.core.rays import RayCaster

    p, n = np.asarray(p, np.float64), np.asarray(n, np.float64)
    out = np.zeros(len(p), bool)
    if len(p) == 0 or len(positions) < 2:
        return out
    delta = COINCIDENT_EPSILONS * RayCaster(positions).epsilon
    rng = np.random.default_rng(seed)
    for _ in range(SPLITS):
        half = rng.random(len(positions)) < 0.5
        for side in (False, True):
            others = np.flatnonzero(half != side)
            own = np.flatnonzero((half[triangle] == side) & ~out)
            if len(others) == 0 or len(own) == 0:
                continue
            caster = RayCaster(positions[others])
            hits = caster.intersect(p[own] + delta * n[own], -n[own], t_max=2.0 * delta)
            u, v = hits.barycentric[:, 0], hits.barycentric[:, 1]
            # Off the other triangle's edges: a sample on an edge two coplanar neighbours share is
            # no overlap.
            inside = hits.hit & (np.minimum(np.minimum(u, v), 1.0 - u - v) > EDGE_MARGIN)
            out[own[inside]] = True
    return out
