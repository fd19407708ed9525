"""The competitors bench's arithmetic (bench/competitors.py) on synthetic images: no Cycles, no OIDN."""
from __future__ import annotations

import numpy as np
import pytest

from pdic.bench import competitors


def _field(h: int, w: int) -> np.ndarray:
    """A smooth positive (h, w, 3) image, like a light map without noise."""
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    base = 1.0 + 0.5 * np.sin(6 * x) * np.cos(4 * y)
    return np.stack([base, 0.8 * base, 0.6 * base], axis=2).astype(np.float32)


def test_noise_corrected_error_recovers_bias_under_reference_noise():
    """A 5 % biased image against a pair far noisier than 5 % (sizes not multiples of the block)."""
    h, w = 300, 260
    truth = _field(h, w)
    mask = np.ones((h, w), bool)
    mask[:, :30] = False
    rng = np.random.default_rng(1)
    pair = tuple(truth * (1 + 0.3 * rng.standard_normal(truth.shape)).astype(np.float32) for _ in range(2))
    test = truth * 1.05
    expected = np.sqrt(np.mean(((test - truth)[mask]) ** 2)) / truth[mask].mean()
    err = competitors.errors(test, pair, mask)
    assert err["texel"] == pytest.approx(expected, rel=0.1)
    assert err["block"] == pytest.approx(expected, rel=0.1)
    naive = np.sqrt(np.mean(((test - 0.5 * (pair[0] + pair[1]))[mask]) ** 2)) / truth[mask].mean()
    assert naive > 2 * expected  # what the correction removes


def test_block_error_forgives_noise_that_averages_out_in_a_block():
    """+-20 % in a checkerboard (zero mean over each 8x8 block): large per texel, none per block."""
    h, w = 64, 64
    truth = _field(h, w)
    mask = np.ones((h, w), bool)
    checker = np.where((np.add.outer(np.arange(h), np.arange(w)) % 2) == 0, 1.2, 0.8)[..., None]
    err = competitors.errors(truth * checker, (truth, truth), mask)
    assert err["texel"] > 0.15
    assert err["block"] < 0.01


def test_block_means_ignore_uncovered_texels():
    image = np.zeros((10, 10, 3), np.float32)
    mask = np.zeros((10, 10), bool)
    image[0, 0], mask[0, 0] = 4.0, True  # one covered texel in the first block
    image[9, 9], mask[9, 9] = 2.0, True  # one in the padded last block
    means, blocks = competitors.block_means(image, mask, 8)
    assert means.shape == (2, 2, 3) and blocks.tolist() == [[True, False], [False, True]]
    assert means[0, 0, 0] == 4.0 and means[1, 1, 0] == 2.0


def _ladder(errors_at_cpu):
    return [dict(method="Cycles", kind="all", cpu=t, error_texel=e) for t, e in errors_at_cpu]


def test_blocks_off_counts_the_blocks_more_than_20_percent_off_and_judges_no_dark_one():
    """Issue #11's block criterion (bench.run.blocks_off): one block 30 % bright, one 15 %, one dark
    block 50 % off but under BLOCK_LIT of the mean; sizes not multiples of the block."""
    from pdic.bench.run import blocks_off

    h, w = 68, 60
    truth = _field(h, w)
    truth[40:48, 0:8] *= 0.01  # a dark block, not judged
    test = truth.copy()
    test[0:8, 0:8] *= 1.3
    test[8:16, 8:16] *= 1.15
    test[40:48, 0:8] *= 1.5
    covered = np.ones((h, w), bool)
    pair = ({"images": {"o": truth}, "coverage": {"o": covered}},) * 2
    judged, off = blocks_off({"o": test}, {"o": covered}, pair)
    assert off == 1 and judged == 8 * 9 - 1
    rel, ok, _, _ = competitors.block_differences(test, truth, covered)
    assert rel[0, 0] == pytest.approx(0.3) and rel[1, 1] == pytest.approx(0.15) and not ok[5, 0]


def test_blocks_off_by_fill_sorts_blocks_by_the_texels_judged_and_judges_the_pair_by_itself():
    """A block of one texel 30 % bright and a full block 25 % bright are off in their own bands; where the
    pair's second bake is 60 % bright, the test (the first bake's value) is 23 % off their mean and the
    two bakes 37.5 % off each other."""
    from pdic.bench.run import blocks_off_by_fill

    h, w = 32, 32
    truth = _field(h, w)
    covered = np.ones((h, w), bool)
    covered[0:8, 0:8] = False
    covered[3, 3] = True  # block (0, 0) holds one texel
    covered[8:16, 0:8] = False
    covered[8:14, 0:1] = True  # block (1, 0) holds six
    test = truth.copy()
    test[3, 3] *= 1.3
    test[16:24, 16:24] *= 1.25
    second = truth.copy()
    second[24:32, 24:32] *= 1.6
    pair = ({"images": {"o": truth}, "coverage": {"o": covered}}, {"images": {"o": second}, "coverage": {"o": covered}})
    bands = blocks_off_by_fill({"o": test}, {"o": covered}, pair)
    assert [band[:2] for band in bands] == [(1, 4), (4, 8), (8, 16), (16, 65)]
    assert [band[2] for band in bands] == [1, 1, 0, 14]
    assert [band[3] for band in bands] == [1, 0, 0, 2]
    assert [band[4] for band in bands] == [0, 0, 0, 1]


def test_equal_error_time_follows_the_ladder_log_log():
    rows = _ladder([(t, 1 / np.sqrt(t)) for t in (1.0, 4.0, 16.0, 64.0)])  # Monte Carlo: error ~ t^-1/2
    at = lambda e: competitors.cycles_cpu_at_error(rows, "Cycles", "all", "texel", e)  # noqa: E731
    assert at(0.3)[0] == pytest.approx(1 / 0.3 ** 2) and at(0.3)[1] == "interpolated"
    assert at(0.1)[0] == pytest.approx(100.0) and at(0.1)[1] == "extrapolated"
    assert at(2.0) == (1.0, "at most")


def test_equal_error_is_none_where_a_denoised_ladder_stops_falling():
    rows = _ladder([(1.0, 0.05), (4.0, 0.031), (16.0, 0.030)])  # a denoiser's bias floor near 3 %
    assert competitors.cycles_cpu_at_error(rows, "Cycles", "all", "texel", 0.01) == (None, None)


def test_crop_window_centres_on_the_nearest_covered_texel_and_stays_inside():
    h, w = 100, 80
    position = np.zeros((h, w, 3))
    position[..., 0], position[..., 1] = np.mgrid[0:h, 0:w]
    mask = np.ones((h, w), bool)
    mask[50, 50] = False
    assert competitors.crop_window(position, mask, (50.0, 50.0, 0.0), side=20) in {(39, 40), (40, 39), (41, 40),
                                                                                  (40, 41)}
    assert competitors.crop_window(position, mask, (99.0, 79.0, 0.0), side=20) == (80, 60)


def test_mean_ratio_reports_a_uniform_darkening():
    truth = _field(32, 32)
    mask = np.ones((32, 32), bool)
    assert competitors.errors(0.8 * truth, (truth, truth), mask)["mean_ratio"] == pytest.approx(0.8, rel=1e-5)


def test_interior_errors_are_the_errors_over_the_interior_texels():
    h, w = 64, 48
    truth = _field(h, w)
    mask = np.ones((h, w), bool)
    interior = np.zeros((h, w), bool)
    interior[8:56, 8:40] = True
    test = truth.copy()
    test[~interior] *= 3.0  # wrong only at the edges
    err = competitors.errors(test, (truth, truth), mask, interior)
    assert err["texel"] > 0.5
    assert err["texel_interior"] == pytest.approx(0.0, abs=1e-6)
    assert err["block_interior"] == pytest.approx(0.0, abs=1e-6)


def test_interior_texels_leave_out_a_charts_border_ring():
    """A quad filling its 16^2 map: every texel holds 2x2 samples, but the outer ring has neighbours
    outside the map, so 14^2 texels are interior."""
    from pdic.bench.run import interior_texels
    from scenes import quad, quad_scene

    scene = quad_scene([quad([0, 0, 0], [1, 0, 0], [0, 1, 0])], {"plane": (0, 16)}, ())
    inner = interior_texels(scene)["plane"]
    assert inner.shape == (16, 16)
    assert inner.sum() == 14 * 14 and inner[1:15, 1:15].all()


def test_interior_texels_leave_out_texels_on_a_face_duplicated_in_place():
    """Cycles bakes a face another triangle duplicates in place black (bench/coincident.py): a copy of
    the plane's left half facing the same way takes those texels out of the comparison; one facing
    the other way (glued back to back, dark to both bakers) or 5 cm above (a real occluder) does not."""
    from pdic.bench.run import interior_texels
    from scenes import quad, quad_scene

    plane = quad([0, 0, 0], [1, 0, 0], [0, 1, 0])
    for copy, taken in ((quad([0, 0, 0], [0.5, 0, 0], [0, 1, 0]), True),  # same facing, in place
                        (quad([0, 0, 0], [0, 1, 0], [0.5, 0, 0]), False),  # facing the other way
                        (quad([0, 0, 0.05], [0.5, 0, 0], [0, 1, 0]), False)):
        inner = interior_texels(quad_scene([plane], {"plane": (0, 16)}, (), extra=copy))["plane"]
        assert inner[1:15, 8:15].all()  # the right half, clear of the copy
        if taken:
            assert not inner[:, :8].any() and inner.sum() == 14 * 7
        else:
            assert inner.sum() == 14 * 14


def test_comparable_texels_leave_out_texels_with_another_face_in_place_facing_either_way():
    """Comparable texels keep the chart's border ring but leave out texels another face passes through
    within two ray offsets, facing the same way or the other (a zero-thickness wall: Cycles' rays, which
    leave with no offset, stop on it); a face 5 cm above is a real occluder and stays."""
    from pdic.bench.run import comparable_texels
    from scenes import quad, quad_scene

    plane = quad([0, 0, 0], [1, 0, 0], [0, 1, 0])
    for copy, taken in ((quad([0, 0, 0], [0.5, 0, 0], [0, 1, 0]), True),  # same facing, in place
                        (quad([0, 0, 0], [0, 1, 0], [0.5, 0, 0]), True),  # facing the other way
                        (quad([0, 0, 0.05], [0.5, 0, 0], [0, 1, 0]), False)):
        fair = comparable_texels(quad_scene([plane], {"plane": (0, 16)}, (), extra=copy))["plane"]
        assert fair.shape == (16, 16)
        assert fair[:, 9:].all()  # the right half, clear of the copy, border ring included
        if taken:
            assert not fair[:, :8].any()
        else:
            assert fair.all()


def test_cached_references_are_keyed_by_the_light_map_layout():
    """A reference baked on one unwrap must not judge another: the cache key follows the UVs and the mesh."""
    import bpy

    from pdic.pdic_addon.uvmaps import LIGHTMAP_UV

    mesh = bpy.data.meshes.new("layout_key")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [(0, 1, 2)])
    layer = mesh.uv_layers.new(name=LIGHTMAP_UV)
    obj = bpy.data.objects.new("layout_key", mesh)
    try:
        first = competitors.layout_key(obj)
        assert competitors.layout_key(obj) == first and len(first) == 12
        layer.data[1].uv = (0.5, 0.25)
        moved_uv = competitors.layout_key(obj)
        mesh.vertices[2].co = (0, 2, 0)
        assert len({first, moved_uv, competitors.layout_key(obj)}) == 3
    finally:
        bpy.data.objects.remove(obj)
        bpy.data.meshes.remove(mesh)


def test_cycles_coverage_leaves_out_centres_on_a_charts_edge_that_pdic_bakes(tmp_path):
    """A chart whose corners lie on texel centres, as xatlas packs them: PDIC's rasteriser counts the centres
    on its edges as inside, Cycles' bake leaves some of them, and only a margin-0 bake tells which (the
    bench compares the texels both bake). The coverage is cached per layout."""
    import bpy

    from pdic.core.raster import rasterize
    from pdic.pdic_addon.uvmaps import LIGHTMAP_UV

    size = 16
    corners = np.array([(2.5, 3.5), (10.5, 3.5), (10.5, 9.5), (2.5, 9.5)]) / size  # on texel centres
    mesh = bpy.data.meshes.new("edge_chart")
    mesh.from_pydata([(0, 0, 0), (8, 0, 0), (8, 6, 0), (0, 6, 0)], [], [(0, 1, 2, 3)])
    layer = mesh.uv_layers.new(name=LIGHTMAP_UV)
    for loop in mesh.loops:
        layer.data[loop.index].uv = corners[loop.vertex_index]
    obj = bpy.data.objects.new("edge_chart", mesh)
    bpy.context.scene.collection.objects.link(obj)
    try:
        baked = competitors.cycles_coverage(obj, (size, size), tmp_path)
        uv = corners[[[0, 1, 2], [0, 2, 3]]].astype(np.float32)
        pdic = rasterize(uv, size, size, 1).centre_inside.reshape(size, size)
        assert pdic.sum() == 9 * 7  # every centre on the chart or on its edges
        assert (baked & ~pdic).sum() == 0 and baked[4:9, 3:10].all()  # Cycles bakes the centres inside
        assert baked.sum() < pdic.sum()  # ... and leaves some on the edges
        assert len(list(tmp_path.glob("coverage_16x16_*.npy"))) == 1
        np.testing.assert_array_equal(competitors.cycles_coverage(obj, (size, size), tmp_path), baked)
    finally:
        bpy.data.objects.remove(obj)
        bpy.data.meshes.remove(mesh)


def test_the_panel_lit_building_hangs_its_panels_just_under_ceilings_clear_of_walls(blender):
    """bench/scenes.py's PANEL_PLACES: each panel 3 cm under a ceiling (its light all below it), a panel's half
    side and more clear of walls and column tops, the building's 1,600 W shared out among the panels."""
    from mathutils import Vector

    from pdic.bench import scenes as bench_scenes

    bench_scenes.load_occluded_panels()
    lights = [o for o in blender.context.scene.objects if o.type == "LIGHT"]
    assert len(lights) == len(bench_scenes.PANEL_PLACES) == 16
    assert all(o.data.type == "AREA" and o.data.shape == "SQUARE" for o in lights)
    assert sum(o.data.energy for o in lights) == pytest.approx(sum(w for _, _, w in bench_scenes.OCCLUDED_LAMPS))
    depsgraph = blender.context.evaluated_depsgraph_get()
    sideways = [Vector((np.cos(a), np.sin(a), 0.0)) for a in np.linspace(0, 2 * np.pi, 16, endpoint=False)]
    for light in lights:
        origin = light.location.copy()
        up = blender.context.scene.ray_cast(depsgraph, origin, Vector((0, 0, 1)))
        assert up[0] and up[1].z - origin.z == pytest.approx(0.03, abs=1e-4), light.name
        down = blender.context.scene.ray_cast(depsgraph, origin, Vector((0, 0, -1)))
        assert down[0] and origin.z - down[1].z > 2.5, light.name
        for d in sideways:
            # 0.25 m past the panel's edge along its axes (a room 2 column top lies just that far)
            hit = blender.context.scene.ray_cast(depsgraph, origin, d, distance=bench_scenes.PANEL_SIZE - 1e-3)
            assert not hit[0], (light.name, tuple(d))
