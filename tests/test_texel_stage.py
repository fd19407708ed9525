"""The texel stage's shortcuts give what the long way gives.

Validity rays in rounds, one Equation 3 lookup per texel, and lookups found from the
records' side (ball queries) are there for speed (Cornell at 512x512: validity 31.7 ->
5.5 s, lookups 3.3 -> 0.9 s per million samples); each is checked here against the
direct computation it replaces.
"""
import numpy as np
import pytest

from pdic.core.interpolation import CacheLookup
from pdic.core.irradiance_cache import IrradianceCache
from pdic.core.rays import RayCaster
from pdic.core.sampling import cosine_hemisphere, orthonormal_basis
from pdic.core.texels import TexelPoints
from pdic.core.validity import BACKFACE_FRACTION, VALIDITY_RAYS, inside_geometry
from pdic.core.ward import accepted, ward_weight

from scenes import quad


def _floor_with_open_box():
    """A floor and an open-bottomed box resting on it (its faces point outward)."""
    floor = quad([-2, -2, 0], [4, 0, 0], [0, 4, 0])
    box = [quad([-0.5, -0.5, 1], [1, 0, 0], [0, 1, 0]),      # top, facing up
           quad([-0.5, -0.5, 0], [1, 0, 0], [0, 0, 1]),      # front, facing -y
           quad([-0.5, 0.5, 0], [0, 0, 1], [1, 0, 0]),       # back, facing +y
           quad([-0.5, -0.5, 0], [0, 0, 1], [0, 1, 0]),      # left, facing -x
           quad([0.5, -0.5, 0], [0, 1, 0], [0, 0, 1])]       # right, facing +x
    return np.concatenate([floor] + box)


def test_validity_rounds_give_the_verdict_of_all_eight_rays_with_fewer_rays():
    tris = _floor_with_open_box()
    caster = RayCaster(tris)
    face_n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    face_n /= np.linalg.norm(face_n, axis=1, keepdims=True)
    rng = np.random.default_rng(3)
    m = 4000  # floor points, a quarter of them under the box, some near its walls
    p = np.column_stack([rng.uniform(-1.2, 1.2, m), rng.uniform(-1.2, 1.2, m), np.zeros(m)])
    n = np.tile([0.0, 0, 1], (m, 1))
    inside, _, rays = inside_geometry(caster, face_n, p, n, np.random.default_rng(11))
    # The long way: the same eight directions (drawn the same way), all cast.
    local = cosine_hemisphere(np.random.default_rng(11).random((m, VALIDITY_RAYS, 2)))[0]
    t1, t2 = orthonormal_basis(n)
    d = (local[..., :1] * t1[:, None] + local[..., 1:2] * t2[:, None] + local[..., 2:3] * n[:, None]).reshape(-1, 3)
    hits = caster.intersect(np.repeat(p, VALIDITY_RAYS, axis=0), d, normals=np.repeat(n, VALIDITY_RAYS, axis=0))
    back = np.zeros(len(d), bool)
    back[hits.hit] = np.einsum("ij,ij->i", face_n[hits.triangle[hits.hit]], d[hits.hit]) > 0
    expected = back.reshape(m, VALIDITY_RAYS).mean(axis=1) > BACKFACE_FRACTION
    assert np.array_equal(inside, expected)
    under = (np.abs(p[:, 0]) < 0.45) & (np.abs(p[:, 1]) < 0.45)
    assert inside[under].all() and not inside[np.abs(p).max(axis=1) > 0.6].any()
    assert rays < 0.75 * m * VALIDITY_RAYS  # most samples leave after four rays


def test_per_texel_points_are_weighted_centroids_per_triangle():
    # Texel 0 has three samples on triangle 5 and one on triangle 6; texel 1 one sample.
    p = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5], [9, 9, 0]])
    n = np.tile([0.0, 0, 1], (5, 1))
    points = TexelPoints(p=p, n_shading=n, n_geometric=n, triangle=np.array([5, 5, 5, 6, 5]),
                         barycentric=np.zeros((5, 2)), target=np.zeros(5, np.int32),
                         texel=np.array([0, 0, 0, 0, 1]), weight=np.array([0.5, 0.25, 0.25, 1.0, 1.0], np.float32))
    merged, index = points.per_texel()
    assert len(merged) == 3
    assert np.array_equal(index[:3], [index[0]] * 3) and len(set(index[[0, 3, 4]])) == 3
    centroid = merged.p[index[0]]
    assert np.allclose(centroid, [0.25, 0.25, 0.0])  # (0.5*0 + 0.25*1 + 0.25*0, ...)
    assert np.isclose(merged.weight[index[0]], 1.0) and np.isclose(merged.weight.sum(), points.weight.sum())
    assert np.allclose(merged.p[index[3]], p[3]) and merged.triangle[index[3]] == 6


def test_per_texel_of_some_rows_is_per_texel_of_their_copy_to_the_bit():
    """The texel stage merges the valid samples by their indices, without copying them first."""
    rng = np.random.default_rng(5)
    m = 3000
    n = rng.normal(size=(m, 3))
    points = TexelPoints(p=rng.normal(size=(m, 3)), n_shading=n, n_geometric=n / np.linalg.norm(n, axis=1)[:, None],
                         triangle=rng.integers(0, 9, m), barycentric=rng.random((m, 2)),
                         target=rng.integers(0, 2, m).astype(np.int32), texel=rng.integers(0, 200, m),
                         weight=rng.random(m).astype(np.float32))
    for rows in (np.sort(rng.choice(m, 1700, replace=False)), rng.permutation(m)[:900], np.zeros(0, np.int64)):
        merged, index = points.per_texel(rows)
        copied, copied_index = points.take(rows).per_texel()
        assert len(index) == len(rows) and np.array_equal(index, copied_index)
        for field in TexelPoints.__dataclass_fields__:
            a, b = getattr(merged, field), getattr(copied, field)
            assert a.dtype == b.dtype and np.array_equal(a, b), field


def test_per_texel_groups_come_in_target_texel_triangle_order_whatever_the_key_size():
    """One int64 key where (target, texel, triangle) fit in it, the rows where not: same groups, same order."""
    from pdic.core.texels import _group_key

    rng = np.random.default_rng(3)
    target, texel, triangle = rng.integers(0, 3, 500), rng.integers(0, 40, 500), rng.integers(0, 7, 500)
    rows = np.stack([target, texel, triangle], axis=1)
    expected = np.unique(rows, axis=0, return_index=True, return_inverse=True)
    for big in (0, 2 ** 40):  # 3 x 2^40 x 2^40 texels x triangles overflows an int64: rows are kept
        key = _group_key(target, texel + big, triangle + big)
        assert key.ndim == (2 if big else 1)
        got = np.unique(key, axis=0 if key.ndim == 2 else None, return_index=True, return_inverse=True)
        assert np.array_equal(got[1], expected[1]) and np.array_equal(got[2].ravel(), expected[2].ravel())


def test_lookup_from_the_records_side_equals_equation_3_over_all_records():
    rng = np.random.default_rng(21)
    K = 300
    p = np.column_stack([rng.uniform(0, 4, K), rng.uniform(0, 4, K), rng.normal(0, 0.05, K)])
    nrm = rng.normal([0, 0, 1], 0.3, size=(K, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    E = rng.uniform(0.5, 2.0, size=(K, 3))
    R = 10 ** rng.uniform(-1, 0.5, K)
    cache = IrradianceCache(p=p, n=nrm, E=E, R=R, grad_r=np.zeros((K, 3, 3)), grad_t=np.zeros((K, 3, 3)),
                            photons_used=np.zeros(K, np.int32), hole=np.zeros(K, bool), refined=np.zeros(K, bool))
    q = np.column_stack([rng.uniform(0, 4, 3000), rng.uniform(0, 4, 3000), np.zeros(3000)])
    qn = np.tile([0.0, 0, 1], (3000, 1))
    a = 0.5
    E_q, w_q = CacheLookup(cache, a, use_gradients=False).irradiance(q, qn)
    # Brute force: every record against every point.
    i, k = np.meshgrid(np.arange(len(q)), np.arange(K), indexing="ij")
    i, k = i.ravel(), k.ravel()
    w = ward_weight(q[i], qn[i], p[k], nrm[k], R[k])
    ok = accepted(w, a, q[i], qn[i], p[k], nrm[k], R[k])
    num = np.stack([np.bincount(i[ok], weights=(w * E[k, c])[ok], minlength=len(q)) for c in range(3)], axis=1)
    den = np.bincount(i[ok], weights=w[ok], minlength=len(q))
    assert (den > 0).mean() > 0.5
    assert np.allclose(w_q, den)
    assert np.allclose(E_q[den > 0], num[den > 0] / den[den > 0, None])


def test_a_hole_rounds_lookup_over_its_new_records_is_equation_3_over_the_whole_cache():
    # fill_holes looks up a round's holes among that round's records only: every older record refused
    # those points, each (point, record) pair's verdict being its own (walls, visibility rays, layers).
    from pdic.core.executor import Executor
    from pdic.core.interpolation import interpolate

    caster = RayCaster(_floor_with_open_box())
    rng = np.random.default_rng(4)

    def records(k, z, log_R):
        # a little off the plane, so the visibility rays decide some pairs
        p = np.column_stack([rng.uniform(-2, 2, k), rng.uniform(-2, 2, k), z + rng.uniform(-0.01, 0.01, k)])
        p[np.all(np.abs(p[:, :2]) < 0.5, axis=1) & (z == 0), 2] = 1.0  # none under the box
        nrm = np.tile([0.0, 0, 1], (k, 1))
        return IrradianceCache(p=p, n=nrm, E=rng.uniform(0.5, 2, (k, 3)), R=10 ** rng.uniform(*log_R, k),
                               grad_r=rng.normal(0, 0.1, (k, 3, 3)), grad_t=rng.normal(0, 0.1, (k, 3, 3)),
                               photons_used=np.zeros(k, np.int32), hole=np.zeros(k, bool), refined=np.ones(k, bool))

    old = records(60, 0.0, (-0.7, -0.2))
    new = records(400, 0.0, (-1.0, -0.4)).extend(records(20, 1.0, (-1.0, -0.4)))  # floor, box top
    q = np.column_stack([rng.uniform(-2, 2, 4000), rng.uniform(-2, 2, 4000), np.zeros(4000)])
    qn = np.tile([0.0, 0, 1], (len(q), 1))
    with Executor(1) as executor:
        def lookup(cache, index):
            return interpolate(cache, 0.5, True, q[index], qn[index], executor, None, with_zone=True, caster=caster,
                               layers=True)

        _, w_old, _ = lookup(old, slice(None))
        holes = np.flatnonzero(w_old <= 0)
        whole, alone = lookup(old.extend(new), holes), lookup(new, holes)
    assert 0.2 * len(q) < len(holes) < 0.9 * len(q) and (alone[1] > 0).mean() > 0.25
    for a, b in zip(whole, alone):  # E, w_sum, smallest zone: bit for bit
        assert np.array_equal(a, b)


def _box_bake(deviations, **settings):
    from pdic.core.pipeline import bake
    from pdic.core.scene import PointLight
    from pdic.core.settings import preset

    from scenes import box_faces, quad_scene

    lamp = PointLight("lamp", np.array([0.5, 0.5, 0.8]), np.full(3, 100.0))
    settings = preset("FINAL", photons=20_000, max_bounces=3, threads=1, hemisphere_theta=6, hemisphere_phi=12,
                      deviations=deviations, **settings)
    return bake(quad_scene(box_faces(), {"floor": (0, 64), "back": (1, 64)}, [lamp]), settings)


def test_gap_fill_places_under_one_hole_record_per_hundred_covered_texels():
    # Pass 3 shrinks R_k after pass 2 covered every photon, opening thin gaps between zones. Where hole
    # records are estimated from photons (here photon-path reuse), a refined record read one texel past
    # its zone is the better value: without gap-fill this box places 231 hole records for 8,192 texels.
    from pdic.core.settings import Deviations

    result = _box_bake(Deviations(thin_coverage=False), reuse_photon_paths=True)  # thin-coverage places records
    counters = result.stats["counters"]
    assert counters["hole_records"] <= 0.01 * counters["texels_covered"]
    assert counters["texel_points_unfilled"] == 0
    for name, image in result.indirect.items():
        assert np.isfinite(image).all() and image[result.coverage[name]].min() > 0, name


def test_final_gathers_hole_records_where_gap_fill_would_read_past_zones():
    """Final's standard gathering gathers a hole record at the gap (deviation: gap-fill is not used there):
    a record read past its zone lit a gallery ceiling's texel of Sponza at 1.8x a path tracer's."""
    from pdic.core.settings import Deviations

    on, off = (_box_bake(Deviations(thin_coverage=False, gap_fill=g)) for g in (True, False))
    counters = on.stats["counters"]
    assert counters["hole_records"] == off.stats["counters"]["hole_records"] > 0.02 * counters["texels_covered"]
    for name in on.lightmaps:
        np.testing.assert_array_equal(on.lightmaps[name], off.lightmaps[name])


def test_final_looks_up_samples_in_narrow_zones_and_preview_each_texel_once():
    """Deviation fine-zones is Final's: Preview interpolates each texel once, at its samples' centroid."""
    from pdic.core.pipeline import bake
    from pdic.core.settings import preset

    from scenes import lamp_box

    points = {}
    for quality in ("PREVIEW", "FINAL"):
        counters = bake(lamp_box(32), preset(quality, photons=20_000, threads=1)).stats["counters"]
        points[quality] = counters["texel_points_interpolated"]
        covered = counters["texels_covered"]
    # One point per texel (per triangle, where a texel spans two) against 2x2 samples per texel again.
    assert points["PREVIEW"] < 1.5 * covered
    assert points["FINAL"] - points["PREVIEW"] > 2 * covered


def test_geometry_computes_face_normals_and_areas_once_read_only_and_not_pickled():
    # The texels' stage asks per target and the emissive triangles' light per batch of points: each asks the
    # whole geometry, so it is computed once; read-only, so no caller changes what the others read.
    import pickle

    from scenes import geometry

    g = geometry(np.concatenate([quad([0, 0, 0], [2, 0, 0], [0, 3, 0]), quad([0, 0, 1], [1, 0, 0], [0, 0, 1])]))
    areas, normals = g.areas(), g.face_normals()
    assert g.areas() is areas and g.face_normals() is normals
    np.testing.assert_allclose(areas, [3.0, 3.0, 0.5, 0.5])
    np.testing.assert_allclose(normals[:2], [[0, 0, 1]] * 2)
    for array in (areas, normals):
        with pytest.raises(ValueError, match="read-only"):
            array[0] = 0.0
    copy = pickle.loads(pickle.dumps(g))  # a Dask worker's copy computes its own
    assert "_derived_arrays" not in copy.__dict__ and np.array_equal(copy.areas(), areas)
