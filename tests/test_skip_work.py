"""A bake does only the work its scene needs, shown by the work counters of its stats (manifest).

No timing asserts: reuse is checked through counters (rays, photons, targets
rasterised and shaded); the bench measures the time (``bench/README.md``).
"""
import numpy as np
import pytest

from pdic.core.bake_cache import BakeCache
from pdic.core.direct import EMISSIVE_KEY
from pdic.core.pipeline import bake
from pdic.core.scene import PointLight, SpotLight
from pdic.core.settings import preset

from scenes import BOX_LAMP, bake_samples, box_faces, lamp_box, quad, quad_scene

FLOOR, BACK, CEILING = 0, 1, 2
_box_faces = box_faces
_scene = quad_scene


SETTINGS = preset("PREVIEW", photons=4000, max_bounces=3, threads=1)


def _counters(result) -> dict:
    return result.stats["counters"]


# --------------------------------------------------------------------------- emitters
def test_no_emitter_triangle_sampling_without_emissive_meshes():
    c = _counters(bake(_scene(_box_faces(), {"floor": (FLOOR, 8)}, [BOX_LAMP]), SETTINGS))
    assert c["emissive_triangles"] == 0 and c["shadow_rays_emissive"] == 0
    assert f"shadow_rays_skipped_points:{EMISSIVE_KEY}" not in c
    assert c["photon_emitters"] == 1
    # The same box with a glowing ceiling does sample it.
    material = np.zeros(12, np.int32)
    material[2 * CEILING:2 * CEILING + 2] = 1
    glowing = _scene(_box_faces(), {"floor": (FLOOR, 8)}, [BOX_LAMP], emission=np.array([[0, 0, 0], [1.0, 1, 1]]),
                     materials=material)
    c = _counters(bake(glowing, SETTINGS))
    assert c["emissive_triangles"] == 2 and c["shadow_rays_emissive"] > 0 and c["photon_emitters"] == 2


# --------------------------------------------------------------------------- photons
def test_photons_leaving_an_open_scene_stop_at_once():
    # A lone floor under a lamp: half the photons fly up and out; bounced ones all leave.
    scene = _scene([quad([0, 0, 0], [1, 0, 0], [0, 1, 0])], {"floor": (0, 8)}, [BOX_LAMP])
    result = bake(scene, SETTINGS)
    c = _counters(result)
    # Every photon ray either stores a hit or escapes, and an escaped photon is never traced again.
    assert c["photon_rays"] == c["photons_stored"] + c["photons_escaped"]
    assert c["photons_escaped"] >= c["photons_emitted"] // 2
    assert result.photons.bounce.max() == 0  # nothing comes back after a bounce off the floor


# --------------------------------------------------------------------------- targets
def test_objects_not_baked_are_not_rasterised():
    floor_only = _scene(_box_faces(), {"floor": (FLOOR, 8)}, [BOX_LAMP])
    one = bake(floor_only, SETTINGS)
    two = bake(_scene(_box_faces(), {"floor": (FLOOR, 8), "back": (BACK, 8)}, [BOX_LAMP]), SETTINGS)
    assert _counters(one)["targets_rasterised"] == 1 and _counters(two)["targets_rasterised"] == 2
    floor_samples = len(bake_samples(floor_only, SETTINGS.texel_samples).p)
    assert _counters(one)["texel_samples"] == floor_samples >= 8 * 8 * 4  # only the floor's
    assert list(one.lightmaps) == ["floor"]


def test_objects_not_baked_are_not_unwrapped(blender, tmp_path):
    from pdic.pdic_addon.job import BakeJob
    from pdic.pdic_addon.uvmaps import LIGHTMAP_UV

    bpy = blender
    bpy.ops.mesh.primitive_plane_add(size=2)
    baked = bpy.context.active_object
    bpy.ops.mesh.primitive_cube_add(location=(0, 0, 3))
    other = bpy.context.active_object
    bpy.ops.object.light_add(type="POINT", location=(0, 0, 2))
    job = BakeJob(bpy.context, preset("PREVIEW", photons=1000, default_resolution=16), objects=[baked],
                  output_folder=str(tmp_path), cache_dir=tmp_path / "cache")
    job.prepare()
    try:
        assert list(job.unwraps) == [baked.name]
        assert LIGHTMAP_UV in baked.data.uv_layers and LIGHTMAP_UV not in other.data.uv_layers
        assert [t.name for t in job.extraction.scene.targets] == [baked.name]
    finally:
        job.rollback()


# --------------------------------------------------------------------------- lights
def test_texels_a_light_cannot_reach_cast_no_shadow_rays_for_it():
    # A hard spot straight down over the floor, and a lid above it facing away from it.
    spot = SpotLight("spot", np.array([0.5, 0.5, 0.8]), np.array([0, 0, -1.0]), np.full(3, 100.0),
                     np.radians(20), 0.0)
    lid = quad([0, 0, 0.9], [1, 0, 0], [0, 1, 0])  # normal +z: faces away from the spot below it
    scene = _scene([quad([0, 0, 0], [1, 0, 0], [0, 1, 0]), lid], {"floor": (0, 16), "lid": (1, 16)}, [spot])
    settings = preset("PREVIEW", photons=1000, max_bounces=2, threads=1, indirect=False)
    result = bake(scene, settings)
    c = _counters(result)
    points = bake_samples(scene, settings.texel_samples)
    on_floor = points.target == 0
    floor_samples, lid_samples = int(on_floor.sum()), int((~on_floor).sum())
    # Sample points of the floor inside the cone (positions in [0, 1]^2).
    x, y = (points.p[on_floor, :2] + scene.origin_world[:2]).T
    inside = np.degrees(np.arctan2(np.hypot(x - 0.5, y - 0.5), 0.8)) < 20
    assert c["shadow_rays_spot"] == int(inside.sum())
    assert c["shadow_rays_skipped_points:spot"] == floor_samples - int(inside.sum()) + lid_samples
    assert result.direct["lid"].max() == 0.0


# --------------------------------------------------------------------------- reuse
@pytest.mark.parametrize("quality", ["PREVIEW", "FINAL"])
def test_rebaking_an_unchanged_scene_reuses_photons_cache_and_texels(quality):
    scene = lamp_box(12)
    settings = preset(quality, photons=4000, max_bounces=3, threads=1, hemisphere_theta=6, hemisphere_phi=12)
    store = BakeCache()
    first = bake(scene, settings, cache=store)
    again = bake(scene, settings, cache=store)
    c1, c2 = _counters(first), _counters(again)
    assert c1["photon_rays"] > 0 and c1["rays_cast"] > 0
    assert c2["photon_rays"] == 0 and c2["rays_cast"] == 0
    assert c2["targets_rasterised"] == 0 and c2["targets_shaded_direct"] == 0 and c2["targets_shaded_indirect"] == 0
    assert "bvh" not in again.stats["seconds"]  # not even the BVH is built
    for name in first.lightmaps:
        np.testing.assert_array_equal(first.lightmaps[name], again.lightmaps[name])
    assert len(again.cache) == len(first.cache)
    # Without a cache the same light maps come out: reuse changes nothing but the work.
    fresh = bake(scene, settings)
    for name in first.lightmaps:
        np.testing.assert_array_equal(first.lightmaps[name], fresh.lightmaps[name])


def test_cache_folder_serves_a_new_session(tmp_path):
    scene = _scene(_box_faces(), {"floor": (FLOOR, 8)}, [BOX_LAMP])
    first = bake(scene, SETTINGS, cache=BakeCache(tmp_path))
    again = bake(scene, SETTINGS, cache=BakeCache(tmp_path))  # nothing in memory: read from disk
    assert _counters(again)["photon_rays"] == 0 and _counters(again)["rays_cast"] == 0
    np.testing.assert_array_equal(first.lightmaps["floor"], again.lightmaps["floor"])


@pytest.mark.slow
def test_changing_the_scene_invalidates_the_cache():
    store = BakeCache()
    bake(_scene(_box_faces(), {"floor": (FLOOR, 8)}, [BOX_LAMP]), SETTINGS, cache=store)
    brighter = PointLight("lamp", BOX_LAMP.position, np.full(3, 200.0))
    again = bake(_scene(_box_faces(), {"floor": (FLOOR, 8)}, [brighter]), SETTINGS, cache=store)
    c = _counters(again)
    assert c["photon_rays"] > 0 and c["targets_shaded_direct"] == 1 and c["targets_rasterised"] == 0
    moved = [f + [0, 0, 0.01 * (i == CEILING)] for i, f in enumerate(_box_faces())]
    c = _counters(bake(_scene(moved, {"floor": (FLOOR, 8)}, [BOX_LAMP]), SETTINGS, cache=store))
    assert c["photon_rays"] > 0 and c["targets_shaded_direct"] == 1


@pytest.mark.slow
def test_changing_one_resolution_redoes_only_that_object():
    store = BakeCache()
    settings = preset("FINAL", photons=4000, max_bounces=3, threads=1, hemisphere_theta=6, hemisphere_phi=12)
    before = bake(lamp_box(12), settings, cache=store)
    # Finer back wall: the coarsest texel (hence R_min) is unchanged, so photons and cache are reused.
    after = bake(_scene(_box_faces(), {"floor": (FLOOR, 12), "back": (BACK, 20)}, [BOX_LAMP]), settings, cache=store)
    c = _counters(after)
    assert c["targets_rasterised"] == 1 and c["targets_shaded_direct"] == 1 and c["targets_shaded_indirect"] == 1
    assert c["photon_rays"] == 0 and c.get("refine_rays_cast", 0) == 0
    np.testing.assert_array_equal(before.lightmaps["floor"], after.lightmaps["floor"])
    assert after.lightmaps["back"].shape == (20, 20, 4)
    # A coarser back wall moves R_min: the cache is rebuilt, the photon map still reused.
    coarse = bake(_scene(_box_faces(), {"floor": (FLOOR, 12), "back": (BACK, 8)}, [BOX_LAMP]), settings, cache=store)
    c = _counters(coarse)
    assert c["photon_rays"] == 0 and c["records"] > 0 and c["targets_rasterised"] == 1


@pytest.mark.slow
def test_reused_photon_map_serves_several_caches_without_mixing_them():
    scene = _scene(_box_faces(), {"floor": (FLOOR, 10)}, [BOX_LAMP])
    settings = preset("FINAL", photons=4000, max_bounces=3, threads=1, hemisphere_theta=6, hemisphere_phi=12)
    store = BakeCache()
    first = bake(scene, settings, cache=store)
    other = bake(scene, preset("FINAL", photons=4000, max_bounces=3, threads=1, hemisphere_theta=6,
                               hemisphere_phi=12, a=0.25), cache=store)
    assert _counters(other)["photon_rays"] == 0 and _counters(other)["records"] > 0
    # Back to the first parameters: its stored cache and photon fields were not overwritten.
    again = bake(scene, settings, cache=store)
    np.testing.assert_array_equal(first.lightmaps["floor"], again.lightmaps["floor"])
    np.testing.assert_array_equal(first.photon_lighting.w_sum, again.photon_lighting.w_sum)
