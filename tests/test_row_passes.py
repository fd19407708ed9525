"""Row-wise work over millions of rows (texel samples, photons, zone-grid entries) runs in passes of
ROW_CHUNK rows (core.executor.row_chunks), so its temporaries stay small: the same values, to the bit,
whatever the pass size."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pdic.core import executor
from pdic.core.density import PhotonDensity
from pdic.core.executor import Executor, Progress
from pdic.core.hole_records import _write_fine
from pdic.core.interpolation import interpolate
from pdic.core.irradiance_cache import IrradianceCache
from pdic.core.pipeline import bake
from pdic.core.rays import RayCaster
from pdic.core.scene import World
from pdic.core.settings import preset
from pdic.core.texels import TexelPoints, _sorted_groups, _unsorted
from pdic.core.zone_grid import ZoneGrid

from scenes import quad, quad_scene

X, Y, Z = np.eye(3)


def _maps(result) -> dict:
    return {f"{kind} {name}": image for kind in ("direct", "indirect")
            for name, image in getattr(result, kind).items()}


def _decal_and_box():
    """A 4 x 4 m ground under a white sky, a closed unit box standing on it and a 1 m decal half a ray
    offset over it (contact faces, a sheet, hole records, texels in narrow zones looked up per sample)."""
    ground = quad(np.array([-2.0, -2.0, 0.0]), 4 * X, 4 * Y)
    box = [quad(np.zeros(3), Y, X), quad(Z, X, Y), quad(np.zeros(3), X, Z), quad(Y, Z, X), quad(np.zeros(3), Z, Y),
           quad(X, Y, Z)]
    corner = np.array([-1.5, -1.5, 0.0])
    eps = RayCaster(np.concatenate([ground, *box, quad(corner, X, Y)])).epsilon
    faces = [ground, *box, quad(corner + 0.5 * eps * Z, X, Y)]
    scene = quad_scene(faces, {"ground": (0, 48), "bottom": (1, 8), "top": (2, 8), "decal": (7, 16)}, [])
    return replace(scene, world=World(np.full(3, 1.0)))


def test_a_bake_in_passes_of_a_few_rows_gives_the_maps_of_one_pass(monkeypatch):
    """The scene baked at Final with the default passes and with passes of 97 rows: every map is the same
    to the bit; the ground under the decal and the box's bottom are black, the open ground lit."""
    scene, settings = _decal_and_box(), preset("final")
    whole = bake(scene, settings)
    monkeypatch.setattr(executor, "ROW_CHUNK", 97)
    passes = bake(scene, settings)
    for kind in ("direct", "indirect"):
        for name, image in getattr(whole, kind).items():
            assert np.array_equal(image, getattr(passes, kind)[name]), (kind, name)
    assert whole.stats["counters"]["texel_samples_under_sheet"] >= 100
    ground = whole.as_cycles("ground")
    assert ground[9:15, 9:15].max() == 0 and ground[40:46, 40:46].mean() > 0.5  # under the decal; open ground
    assert whole.as_cycles("bottom").max() == 0


def test_equation_3_at_some_rows_of_a_set_is_equation_3_at_those_points():
    """interpolate(rows=...) looks up rows of p, n chunk by chunk: what it gives at the points themselves."""
    rng = np.random.default_rng(5)
    K = 2000
    p_k = np.column_stack([rng.random((K, 2)) * 4.0, np.zeros(K)])
    cache = IrradianceCache(p=p_k, n=np.tile(Z, (K, 1)), E=rng.random((K, 3)), R=0.2 + 0.3 * rng.random(K),
                            grad_r=0.1 * rng.normal(size=(K, 3, 3)), grad_t=0.1 * rng.normal(size=(K, 3, 3)),
                            photons_used=np.zeros(K, np.int32), hole=np.zeros(K, bool), refined=np.ones(K, bool))
    p = np.column_stack([rng.random((90000, 2)) * 4.0, np.zeros(90000)])
    n = np.tile(Z, (len(p), 1))
    rows = np.sort(rng.choice(len(p), 70000, replace=False))
    with Executor(2) as pool:
        got = interpolate(cache, 0.4, True, p, n, pool, Progress(), with_zone=True, rows=rows)
        want = interpolate(cache, 0.4, True, p[rows], n[rows], pool, Progress(), with_zone=True)
    assert (want[1] > 0).mean() > 0.9
    for a, b in zip(got, want):
        assert np.array_equal(a, b)


def test_a_zone_grid_built_in_passes_lists_what_one_pass_lists(monkeypatch):
    rng = np.random.default_rng(3)
    p = rng.random((700, 3)) * [4.0, 3.0, 0.5]
    zone = 0.02 + 0.5 * rng.random(700) ** 3
    whole = ZoneGrid(p, zone)
    monkeypatch.setattr(executor, "ROW_CHUNK", 13)
    passes = ZoneGrid(p, zone)
    assert whole.entries == passes.entries > 13 * 50
    for name in ("records", "entry_p", "entry_zone2", "first", "cells", "start", "stop"):
        assert np.array_equal(getattr(whole, name, None), getattr(passes, name, None)), name
    q = rng.random((5000, 3)) * [4.0, 3.0, 0.5]
    for a, b in zip(whole.pairs(q), passes.pairs(q)):
        assert np.array_equal(a, b)


def _groups(key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """np.unique's first indices and inverse from :func:`_sorted_groups`."""
    order, first, inverse = _sorted_groups(key)
    assert order is not None or key.ndim == 1  # rows are always sorted
    return (first if order is None else order[first]), _unsorted(order, inverse)


def test_sorted_sample_keys_are_grouped_as_np_unique_groups_them():
    """Keys in order (rasterised samples) are grouped where they change, without a sort: np.unique's first
    indices and inverse, dtypes included; unsorted and row keys by a stable sort, to the same answer."""
    rng = np.random.default_rng(4)
    assert _sorted_groups(np.sort(rng.integers(0, 9, 40)))[0] is None
    for n in (1, 2, 50, 20000):
        key = np.sort(rng.integers(0, max(n // 4, 1), n))
        first, inverse = _groups(key)
        _, want_first, want_inverse = np.unique(key, return_index=True, return_inverse=True)
        assert np.array_equal(first, want_first) and np.array_equal(inverse, want_inverse.ravel())
        assert first.dtype == want_first.dtype and inverse.dtype == want_inverse.dtype and inverse.ndim == 1
    unsorted = np.array([5, 3, 5, 1, 3])
    first, inverse = _groups(unsorted)
    assert first.tolist() == [3, 1, 0] and inverse.tolist() == [2, 1, 2, 0, 1]
    rows = np.array([[0, 2, 1], [0, 1, 7], [0, 2, 1]])
    first, inverse = _groups(rows)
    assert first.tolist() == [1, 0] and inverse.tolist() == [1, 0, 1]


def test_fine_samples_write_their_own_light_where_a_record_covers_them():
    """The fine-zone lookup's write-back: covered samples take their own E, the rest keep their texel's."""
    E = np.arange(18, dtype=np.float64).reshape(6, 3)
    samples = np.array([1, 3, 4])
    E_fine = np.full((3, 3), -1.0)
    _write_fine(E, samples, E_fine, np.array([0.5, 0.0, np.nan]))
    assert E[1].tolist() == [-1.0] * 3 and E[3].tolist() == [9.0, 10.0, 11.0] and E[4].tolist() == [12.0, 13.0, 14.0]
    assert E[[0, 2, 5]].tolist() == [[0.0, 1.0, 2.0], [6.0, 7.0, 8.0], [15.0, 16.0, 17.0]]


def test_photons_per_side_in_passes_counts_what_one_pass_counts(monkeypatch):
    """Each triangle's photons on its front and its back (the photons' sides taken in passes of 7)."""
    scene = _decal_and_box()
    photons = bake(scene, preset("preview")).photons
    face_normals = scene.geometry.face_normals()
    front, back = PhotonDensity(photons).photons_per_side(face_normals)
    monkeypatch.setattr(executor, "ROW_CHUNK", 7)
    assert all(np.array_equal(a, b) for a, b in zip((front, back), PhotonDensity(photons).photons_per_side(face_normals)))
    behind = np.einsum("ij,ij->i", photons.n.astype(np.float64), face_normals[photons.triangle]) < 0
    assert np.array_equal(back, np.bincount(photons.triangle[behind], minlength=len(face_normals)))
    assert front.sum() + back.sum() == len(photons.triangle) > 10000
    assert front[-2:].sum() > 100 and back[:2].sum() > 100  # the decal's top, the ground's underside (open sky)


def _per_texel_at_once(points: TexelPoints, rows: np.ndarray):
    """per_texel's centroids over all of ``rows``' samples at once (np.unique's groups, whole-column sums)."""
    key = np.stack([points.target[rows], points.texel[rows], points.triangle[rows]], axis=1)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    weight = points.weight[rows]
    total = np.bincount(inverse, weights=weight.astype(np.float64))
    w = np.where(total[inverse] > 0, weight.astype(np.float64), 1.0)
    total = np.bincount(inverse, weights=w)

    def mean(values):
        return np.stack([np.bincount(inverse, weights=w * values[rows, c]) / total
                         for c in range(values.shape[1])], axis=1)

    return mean(points.p), mean(points.n_shading), mean(points.barycentric), first, inverse


def test_per_texel_sums_each_group_in_one_pass_as_all_rows_at_once(monkeypatch):
    """Samples merged per (target, texel, triangle) in passes of 7 rows, each group whole in one pass: the
    centroids (and their weights, normals unnormalised) are those of one pass over every row, to the bit,
    with keys in order (as rasterised) and not, groups of zero weight included."""
    monkeypatch.setattr(executor, "ROW_CHUNK", 7)
    rng = np.random.default_rng(6)
    m = 400
    weight = rng.random(m).astype(np.float32)
    weight[:12] = 0.0  # the first texel's samples: a group whose weights sum to zero
    points = TexelPoints(p=rng.normal(size=(m, 3)), n_shading=rng.normal(size=(m, 3)),
                         n_geometric=rng.normal(size=(m, 3)), triangle=rng.integers(0, 3, m),
                         barycentric=rng.random((m, 2)), target=np.zeros(m, np.int32),
                         texel=np.sort(rng.integers(0, 40, m)), weight=weight)
    points = points.take(np.lexsort((points.triangle, points.texel)))  # in key order, as rasterised
    points = replace(points, texel=np.where(np.arange(m) < 12, 0, points.texel))
    for rows in (np.arange(m), np.sort(rng.choice(m, 300, replace=False)), rng.permutation(m)[:350]):
        merged, inverse = points.per_texel(rows)
        p, n_s, bary, first, want_inverse = _per_texel_at_once(points, rows)
        assert np.array_equal(inverse, want_inverse) and inverse.dtype == np.intp
        assert np.array_equal(merged.p, p) and np.array_equal(merged.barycentric, bary)
        length = np.linalg.norm(n_s, axis=1, keepdims=True)
        assert np.array_equal(merged.n_shading, np.where(length > 1e-12, n_s / np.maximum(length, 1e-300),
                                                         points.n_geometric[rows[first]]))
        assert np.array_equal(merged.triangle, points.triangle[rows[first]])
        assert np.array_equal(merged.weight, np.bincount(want_inverse, weights=points.weight[rows]).astype(np.float32))
        assert merged.weight[0] == 0 and np.isfinite(merged.p).all()
    with pytest.raises(TypeError, match="integer indices"):  # a mask would read as rows 0 and 1
        points.per_texel(np.ones(m, bool))
    # Columns already int64, all rows: the keys are built in place in copies, never in the points' own columns.
    wide = replace(points, target=points.target.astype(np.int64))
    before = {f: getattr(wide, f).copy() for f in TexelPoints.__dataclass_fields__}
    merged, _ = wide.per_texel()
    assert all(np.array_equal(getattr(wide, f), before[f]) for f in before)
    assert np.array_equal(merged.p, points.per_texel(np.arange(m))[0].p)
