"""Record validity (deviation: record-validity): a hole record whose gathering rays mostly hit back
faces is inside geometry, by texel validity's rule with a record's many rays."""
from __future__ import annotations

import numpy as np

from pdic.core.rays import RayCaster
from pdic.core.real_rays import RealHits
from pdic.core.refinement import record_inside_geometry
from pdic.core.sampling import cosine_hemisphere, to_world

from scenes import box_faces

CELLS = 16


def _gather(caster, p, n, rays):
    """RealHits of ``rays`` cosine-distributed rays from each record (p, n (B, 3)), cell = record * CELLS + ray."""
    B = len(p)
    origin = np.repeat(p, rays, axis=0)
    direction = to_world(cosine_hemisphere(np.random.default_rng(0).random((B * rays, 2)))[0], np.repeat(n, rays, 0))
    hits = caster.intersect(origin, direction)
    cell = np.repeat(np.arange(B) * CELLS, rays) + np.tile(np.arange(rays), B)
    h = hits.hit
    return RealHits(cell[h], hits.triangle[h], hits.barycentric[h], origin[h] + direction[h] * hits.t[h, None],
                    direction[h], hits.t[h])


def test_a_record_inside_a_closed_solid_is_inside_and_one_above_it_is_not():
    solid = np.concatenate([face[:, ::-1] for face in box_faces()])  # the unit cube, normals outward
    caster = RayCaster(solid)
    p = np.array([[0.5, 0.5, 0.01], [0.5, 0.5, 1.5], [0.5, 0.5, 1.01]])
    n = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])  # inside; above, looking up; on top, looking down
    real = _gather(caster, p, n, CELLS)
    assert record_inside_geometry(caster, real, CELLS, np.full(3, CELLS)).tolist() == [True, False, False]
    # Fewer real rays than texel validity's eight (photons lent the other cells' light): no verdict.
    assert not record_inside_geometry(caster, real, CELLS, np.full(3, 4)).any()
