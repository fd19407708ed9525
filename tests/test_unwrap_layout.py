"""Light-map layouts never overlap: the overlap test itself, the repairs, growing maps, xatlas crashes."""
from __future__ import annotations

import numpy as np
import pytest
from test_unwrap import quad_grid, wavy

from pdic.core import unwrap as unwrap_module
from pdic.core.executor import Cancelled
from pdic.core.unwrap import DegenerateMeshError, PackError, UnwrapCrashed, loop_uvs, unwrap
from pdic.core.uv_overlap import overlapping_triangles, uv_overlaps


def flat(x, y):
    return 0 * x


def square(origin, u_axis, v_axis):
    """Positions (4, 3) and two triangles of a unit square at ``origin`` spanned by the axes."""
    o, u, v = (np.asarray(a, np.float64) for a in (origin, u_axis, v_axis))
    return np.array([o, o + u, o + u + v, o + v]), np.array([[0, 1, 2], [0, 2, 3]])


def merge(*parts):
    """Concatenate (positions, triangles) pieces into one mesh; polygons = one per triangle pair."""
    positions, triangles, base = [], [], 0
    for p, t in parts:
        positions.append(p)
        triangles.append(t + base)
        base += len(p)
    t = np.concatenate(triangles)
    return np.concatenate(positions), t


# --------------------------------------------------------------------------- the test itself
def test_uv_overlaps_counts_texel_centres_inside_two_triangles_not_shared_edges():
    square_uv = np.array([[[0, 0], [0.5, 0], [0.5, 0.5]], [[0, 0], [0.5, 0.5], [0, 0.5]]], np.float32)
    assert uv_overlaps(square_uv, None, 16, 16) == 0  # two triangles sharing a diagonal
    shifted = square_uv + np.float32(0.25)
    both = np.concatenate([square_uv, shifted])
    # a 4x4-texel intersection; its 4 centres on both squares' diagonal are on edges, not inside
    assert uv_overlaps(both, None, 16, 16) == 12
    assert overlapping_triangles(both, None, 16, 16).tolist() == [True, True, True, True]
    loops = np.arange(12).reshape(4, 3)  # the same test through an index array
    assert uv_overlaps(both.reshape(-1, 2), loops, 16, 16) == 12


def test_uv_overlaps_is_fast_enough_for_a_large_layout():
    p, t, poly, _ = quad_grid(160, flat)  # 51,200 triangles, tiled over the whole map
    uv = p[t][:, :, :2].astype(np.float32)
    assert uv_overlaps(uv, None, 2048, 2048) == 0
    uv[0] += np.float32(0.001)  # one triangle slid over its neighbours
    assert uv_overlaps(uv, None, 2048, 2048) > 0


# --------------------------------------------------------------------------- repairs
def test_degenerate_polygon_between_three_charts_covers_no_texel():
    """A zero-area triangle whose vertices lie in three different charts used to take
    a UV from each chart and span the map across other charts."""
    a = square((0, 0, 0), (-1, 0, 0), (0, -1, 0))
    b = square((5, 0, 0), (0, 1, 0), (0, 0, 1))
    c = square((10, 0, 0), (1, 0, 0), (0, 0, -1))
    p, t = merge(a, b, c)
    t = np.concatenate([t, [[0, 4, 8]]])  # collinear corners of the three squares
    poly = np.array([0, 0, 1, 1, 2, 2, 3])
    r = unwrap(p, t, 64, 2, triangle_polygon=poly)
    assert r.chart[-1] == -1 and r.chart_count == 3
    assert uv_overlaps(r.uv, None, 64, 64, 4) == 0
    e1, e2 = r.uv[-1, 1] - r.uv[-1, 0], r.uv[-1, 2] - r.uv[-1, 0]
    assert e1[0] * e2[1] - e1[1] * e2[0] == 0  # zero UV area, as in 3-D


def test_stacked_faces_triangulated_differently_get_separate_uvs():
    """Coplanar faces with their own vertices on top of each other (Sponza has such):
    xatlas may fold them into one chart; the repair detaches them."""
    p, t, poly, loops = quad_grid(6, wavy)
    a, b, c, d = t[:36, 0], t[:36, 1], t[:36, 2], t[36:, 2]
    t2 = np.concatenate([np.stack([a, b, d], -1), np.stack([b, c, d], -1)]) + len(p)  # the other diagonal
    positions = np.concatenate([p, p])
    triangles = np.concatenate([t, t2])
    polygon = np.concatenate([poly, poly + 36])
    r = unwrap(positions, triangles, 64, 2, triangle_polygon=polygon, max_resolution=1024)
    assert uv_overlaps(r.uv, None, r.resolution, r.resolution, 4) == 0
    q = 4 * np.arange(36) + 4 * 36  # loops of the copy: a, b, c, d = q, q + 1, q + 2, q + 3
    loops2 = np.concatenate([np.stack([q, q + 1, q + 3], -1), np.stack([q + 1, q + 2, q + 3], -1)])
    assert loop_uvs(r.uv, np.concatenate([loops, loops2]), 8 * 36)[1] == 0  # still one UV per corner


def test_duplicate_faces_are_unwrapped_without_overlap():
    p, t, poly, _ = quad_grid(8, wavy)
    r = unwrap(p, np.concatenate([t, t]), 128, 2, triangle_polygon=np.concatenate([poly, poly + 64]),
               max_resolution=1024)
    assert uv_overlaps(r.uv, None, r.resolution, r.resolution, 4) == 0


def test_noisy_quads_keep_one_uv_per_corner_and_no_overlap():
    rng = np.random.default_rng(7)
    heights = rng.normal(0, 0.02, (31, 31))
    p, t, poly, loops = quad_grid(30, lambda x, y: heights[(y * 30).round().astype(int), (x * 30).round().astype(int)])
    r = unwrap(p, t, 256, 2, triangle_polygon=poly)
    uv_loop, conflicts = loop_uvs(r.uv, loops, loops.max() + 1)
    assert conflicts == 0
    assert uv_overlaps(uv_loop, loops, 256, 256, 4) == 0


# --------------------------------------------------------------------------- map size
def test_small_map_grows_to_the_smallest_that_packs_and_says_so():
    cube = [square(o, u, v) for o, u, v in [((0, 0, 0), (1, 0, 0), (0, 1, 0)), ((0, 0, 1), (0, 1, 0), (1, 0, 0)),
                                           ((0, 0, 0), (0, 0, 1), (1, 0, 0)), ((0, 1, 0), (1, 0, 0), (0, 0, 1)),
                                           ((0, 0, 0), (0, 1, 0), (0, 0, 1)), ((1, 0, 0), (0, 0, 1), (0, 1, 0))]]
    p, t = merge(*cube)
    with pytest.raises(PackError, match="12x12"):
        unwrap(p, t, 12, 2)  # six charts with their padding need more than 12^2
    r = unwrap(p, t, 12, 2, max_resolution=4096)
    assert r.resolution == 16  # 12 grown by 25 %, a multiple of 4: the first size that packs
    assert uv_overlaps(r.uv, None, r.resolution, r.resolution, 4) == 0
    with pytest.raises(PackError, match="largest allowed map is 12x12"):
        unwrap(p, t, 8, 2, max_resolution=12)


# --------------------------------------------------------------------------- bad input
def test_object_scaled_to_zero_is_a_typed_error_saying_so():
    p, t, poly, _ = quad_grid(3, wavy)
    with pytest.raises(DegenerateMeshError, match="scaled to 0"):
        unwrap(p * 0.0, t, 64, 2, triangle_polygon=poly)


# --------------------------------------------------------------------------- the child process
def test_child_process_gives_the_same_uvs_as_in_process():
    p, t, poly, _ = quad_grid(12, wavy)
    child = unwrap(p, t, 64, 2, triangle_polygon=poly)
    here = unwrap(p, t, 64, 2, triangle_polygon=poly, in_process=True)
    assert np.array_equal(child.uv, here.uv) and np.array_equal(child.chart, here.chart)
    assert child.resolution == here.resolution == 64


def test_cancelled_unwrap_stops_and_raises_cancelled():
    p, t, poly, _ = quad_grid(60, wavy)
    asked = []

    def cancelled():
        asked.append(1)
        return True

    with pytest.raises(Cancelled):
        unwrap(p, t, 256, 2, triangle_polygon=poly, cancelled=cancelled)
    assert asked


def test_xatlas_crash_on_ico_sphere_is_survived_and_reported(blender):
    """xatlas 0.0.11 dies by SIGSEGV on a stock ico sphere with 7 subdivisions (81,920 faces,
    jpcy/xatlas#146): this process lives on and gets an error saying what happened."""
    from pdic.pdic_addon import uvmaps

    blender.ops.mesh.primitive_ico_sphere_add(subdivisions=7)
    tris = uvmaps.mesh_triangles(blender.context.object.data)
    tries = []
    with pytest.raises(UnwrapCrashed, match="SIGSEGV"):
        unwrap(tris.positions, tris.triangles, 256, 2, triangle_polygon=tris.polygon, progress=tries.append)
    assert len(tries) == unwrap_module.CHART_VARIANTS  # every chart-option set was tried


def test_cathedral_unwraps_without_overlap_and_its_pole_triangles_cover_nothing():
    """tests/cathedral.py at low detail (17.6k triangles): the apse dome's pole has zero-area
    triangles whose corners lie in different charts; they used to take one UV from each
    chart and cross the map (901 texel centres inside two triangles at 512^2)."""
    from cathedral import cathedral

    mesh = cathedral(0.2)
    tri, polygon = mesh.triangles()
    r = unwrap(mesh.positions, tri, 512, 2, triangle_polygon=polygon, max_resolution=4096)
    assert uv_overlaps(r.uv, None, r.resolution, r.resolution) == 0
    degenerate = r.chart < 0
    assert degenerate.sum() > 0
    e1, e2 = r.uv[degenerate, 1] - r.uv[degenerate, 0], r.uv[degenerate, 2] - r.uv[degenerate, 0]
    assert np.all(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] == 0)


def test_unwrap_child_that_gives_no_answer_in_time_is_killed_and_reported(monkeypatch):
    """xatlas's thread pool was once seen deadlocked in the child: past its time limit the child
    is killed, retried with the other chart options, and the error says it did not answer."""
    monkeypatch.setattr(unwrap_module, "CHILD_SECONDS_BASE", 0.0)
    monkeypatch.setattr(unwrap_module, "CHILD_SECONDS_PER_TRIANGLE", 0.0)
    p = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    tries = []
    with pytest.raises(UnwrapCrashed, match="no answer within 0 s"):
        unwrap(p, np.array([[0, 1, 2], [0, 2, 3]]), 64, 2, progress=tries.append)
    assert len(tries) == unwrap_module.CHART_VARIANTS
