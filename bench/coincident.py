"""Texel samples on duplicated faces: another triangle facing the same way passes through the sample.

Where two triangles overlap in one plane facing the same way (a mesh's faces duplicated in place),
Cycles' bake is not a reference: its rays leave a surface point with no offset, skip only their own
triangle and hit the duplicate at distance ~0, so the texel bakes black. On Sponza (16 texels/m)
vault and arch faces are duplicated so (mesh triangles 24315-24316 lie over 24400): both reference
seeds bake them exactly 0, a re-bake at 8 spp too, where the path referee (bench/path_referee.py)
traces 1.37 and 1.36 and PDIC 1.37 and 1.36. PDIC's rays leave ``RayCaster.epsilon`` above the
surface, past the duplicate, which is what a light map wants: a renderer shows either face with the
light of the room it faces. Comparisons against Cycles leave out the texels with a sample on such a face
(``bench.run.interior_texels``), and count them: Sponza 204 of its 889,291 interior texels, which
held 44 % of PDIC Final's squared 8x8-block indirect error (per texel / 8x8: 8.31 / 8.46 -> 7.64 /
6.36 % at cff3cab), the generated cathedral 2,455 of 81,374, the occluded building 35 (no change),
the Cornell box none. Faces glued back to back (a stair on a stair, a wall on its slab) face into
each other's solids; both bakers find them dark (the building's 38,940 such texels: 94 % and 96 %
exactly 0), and they stay in the interior texels.

*Either facing*, a triangle passing through the sample facing either way marks the texels
``bench.run.comparable_texels`` leaves out, chart edges included. Where a face lies closer to the sample
than a ray offset the bakers see different geometry. On Sponza held (4 texels/m) 37 texels bake exactly 0
in both Cycles seeds where PDIC finds them lit; same-facing duplicates explain 30 of them, opposite faces
(a zero-thickness wall) 6 more. At five of the 37 the path referee traces 1.32, 1.32, 1.20, 0.77 and
0.65 (PDIC 1.31, 1.28, 1.21, 0.72, 0.70). Four texels on one-triangle charts 4 cm long, in the seam
where an ornament's mirrored halves meet at a plane, read 4.6 in Cycles and 1.2 in PDIC; there the
referee traces 1.24 at a point and 0.28 a millimetre away. Those 4 of 116,241 texels held 28 % of
PDIC's systematic squared error.

The test casts, from COINCIDENT_EPSILONS epsilons above each sample, a ray back through it over
twice that distance against the triangles of the other half of a random split of the mesh: a hit
is a triangle within that distance of the plane at the sample, and it counts if it faces the same
side. A duplicated pair falls in different halves with probability 1/2 per split; SPLITS splits
miss it with probability 2^-SPLITS.
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
                       seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """((m,) bool, (m,) bool): samples p (m, 3) on ``triangle`` (m,) facing their face normal n (m, 3)
    through which another triangle of ``positions`` (T, 3, 3) passes (within COINCIDENT_EPSILONS
    epsilons) facing the same side, and facing either side (*either facing* above), from one pass."""
    from pdic.core.rays import RayCaster

    p, n = np.asarray(p, np.float64), np.asarray(n, np.float64)
    same, either = np.zeros(len(p), bool), np.zeros(len(p), bool)
    if len(p) == 0 or len(positions) < 2:
        return same, either
    delta = COINCIDENT_EPSILONS * RayCaster(positions).epsilon
    rng = np.random.default_rng(seed)
    for _ in range(SPLITS):
        half = rng.random(len(positions)) < 0.5
        for side in (False, True):
            others = np.flatnonzero(half != side)
            own = np.flatnonzero((half[triangle] == side) & ~same)  # a same-facing sample is settled both ways
            if len(others) == 0 or len(own) == 0:
                continue
            caster = RayCaster(positions[others])
            hits = caster.intersect(p[own] + delta * n[own], -n[own], t_max=2.0 * delta)
            u, v = hits.barycentric[:, 0], hits.barycentric[:, 1]
            # Off the other triangle's edges: a sample on an edge two coplanar neighbours share is
            # no overlap.
            inside = hits.hit & (np.minimum(np.minimum(u, v), 1.0 - u - v) > EDGE_MARGIN)
            either[own[inside]] = True
            # Facing the same way: a duplicate. Two faces glued back to back (a stair on a stair, a
            # wall on its slab) face into each other's solids, and both bakers find them dark.
            facing = np.einsum("ij,ij->i", caster.face_normals[np.maximum(hits.triangle, 0)], n[own]) > 0
            same[own[inside & facing]] = True
    return same, either
