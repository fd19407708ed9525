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


def test_a_hole_record_inside_a_solid_keeps_its_zero_to_a_zone_of_its_own():
    """A hole record inside a closed box on a floor gathers back faces: E = 0, as a path tracer finds at
    its point, but only there. At R_k its zone reached lit texels beside the solid (Sponza held: a
    capital's flank read 0.56x a path tracer 5 cm from such a record); it keeps INSIDE_RECORD_RADIUS
    R_min. A record on the lit floor beside the box keeps its gathered radius and its light."""
    from pdic.core.constants import INSIDE_RECORD_RADIUS
    from pdic.core.density import PhotonDensity
    from pdic.core.executor import serial_executor
    from pdic.core.interpolation import CacheLookup
    from pdic.core.irradiance_cache import CacheParameters, IrradianceCache, Zones
    from pdic.core.photons import PhotonLighting, trace_photons
    from pdic.core.refinement import GatherSources, refine_records
    from pdic.core.scene import PointLight
    from pdic.core.settings import Deviations, preset

    from scenes import closed_box, lit, quad

    tris = np.concatenate([quad([-2, -2, 0], [4, 0, 0], [0, 4, 0])] + closed_box([-0.5, -0.5, 0.0], [0.5, 0.5, 1.0]))
    scene = lit(tris, PointLight("p", np.array([1.5, 0.0, 2.0]), np.full(3, 100.0)))
    caster = RayCaster(tris)
    photons, _ = trace_photons(scene, caster, 4000, 3, seed=1)
    lighting = PhotonLighting.zeros(len(photons))
    lighting.w_sum[:] = 1.0
    lighting.E_indirect_sum[:] = 1.0  # every gathering hit no record accepts reads 1 W/m^2 of indirect light
    nowhere = IrradianceCache(p=np.array([[50.0, 0, 0]]), n=np.array([[0.0, 0, 1]]), E=np.ones((1, 3)),
                              R=np.array([0.1]), grad_r=np.zeros((1, 3, 3)), grad_t=np.zeros((1, 3, 3)),
                              photons_used=np.zeros(1, np.int32), hole=np.zeros(1, bool), refined=np.zeros(1, bool))
    sources = GatherSources(PhotonDensity(photons), lighting, CacheLookup(nowhere, 0.4, use_gradients=False), None,
                            Deviations())
    params = CacheParameters(a=0.4, r_nearest=16, R_min=0.1, R_max=1.0)
    p = np.array([[0.0, 0.0, 0.01], [1.0, 0.0, 0.0]])  # inside the box, on the floor beside it
    up = np.tile([0.0, 0.0, 1.0], (2, 1))
    holes = IrradianceCache(p=p, n=up, E=np.zeros((2, 3)), R=np.full(2, params.R_min), grad_r=np.zeros((2, 3, 3)),
                            grad_t=np.zeros((2, 3, 3)), photons_used=np.zeros(2, np.int32), hole=np.ones(2, bool),
                            refined=np.zeros(2, bool))
    settings = preset("FINAL", threads=1, hemisphere_theta=6, hemisphere_phi=12)
    refined, counters = refine_records(scene, caster, sources, holes, Zones([np.zeros(0, np.int32)] * 2), settings,
                                       params, serial_executor())
    assert counters["refine_records_inside"] == 1
    assert not refined.E[0].any() and refined.R[0] == INSIDE_RECORD_RADIUS * params.R_min
    assert (refined.E[1] > 0).all() and refined.R[1] >= params.R_min
