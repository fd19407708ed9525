"""Light portals (deviation portal-photons, core/portals.py): the sun's and the world's photons sent through a
window carry the same light into the room as without the portal, many more of them."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from pdic.core.lights import unused_portals
from pdic.core.pipeline import bake
from pdic.core.photons import trace_photons
from pdic.core.rays import RayCaster
from pdic.core.scene import AreaLight, BakeTarget, Materials, Scene, SunLight, World
from pdic.core.settings import Deviations, preset
from scenes import UV_QUAD, geometry, quad, recentre

ROOM = (4.0, 4.0, 3.0)
WINDOW = ((1.5, 2.5), (1.0, 2.0))
"""The window's x and z extent in the room's front wall (y = 0): 1 m^2."""


def window_room() -> tuple[Scene, AreaLight]:
    """A 4 x 4 x 3 m room of single faces, a 1 m^2 hole in its front wall, under a white sky; its floor the bake
    target; and a portal filling the hole, facing in."""
    L, W, H = ROOM
    (x0, x1), (z0, z1) = WINDOW
    faces = [quad([0, 0, 0], [L, 0, 0], [0, W, 0]), quad([0, 0, H], [0, W, 0], [L, 0, 0]),
             quad([0, W, 0], [0, 0, H], [L, 0, 0]), quad([0, 0, 0], [0, 0, H], [0, W, 0]),
             quad([L, 0, 0], [0, W, 0], [0, 0, H]),
             quad([0, 0, 0], [x0, 0, 0], [0, 0, H]), quad([x1, 0, 0], [L - x1, 0, 0], [0, 0, H]),
             quad([x0, 0, 0], [x1 - x0, 0, 0], [0, 0, z0]), quad([x0, 0, z1], [x1 - x0, 0, 0], [0, 0, H - z1])]
    local, origin = recentre(np.concatenate(faces))
    target = np.full(len(local), -1, np.int32)
    target[:2] = 0
    scene = Scene(geometry(local, target=target), Materials.default(1), world=World(radiance=np.ones(3, np.float32)),
                  targets=(BakeTarget("floor", np.array([0, 1]), UV_QUAD, 16, 16),), origin_world=origin)
    portal = AreaLight("window", np.array([(x0 + x1) / 2, 0.0, (z0 + z1) / 2]) - origin, np.array([0.0, 1.0, 0.0]),
                       np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), x1 - x0, z1 - z0, "RECTANGLE", np.zeros(3))
    return scene, portal


def entering(scene: Scene, photons: int, seed: int) -> tuple[float, int]:
    """(the power of the photons that land inside the room on their first hit, how many there are)."""
    ph, _ = trace_photons(scene, RayCaster(scene.geometry.positions), photons, 0, seed)
    q = ph.p + 0.01 * ph.n + scene.origin_world  # just off the surface, on the side the photon came from
    inside = np.all((q > 0) & (q < ROOM), axis=1) & (ph.bounce == 0)
    return float(ph.power[inside].astype(np.float64).mean(axis=1).sum()), int(inside.sum())


@pytest.mark.parametrize("light", ["world", "sun"])
def test_portal_photons_bring_the_same_light_through_the_window(light):
    room, portal = window_room()
    if light == "sun":  # travelling in at cos 0.808 to the window's normal; S A cos through the window
        toward = np.array([0.3, -0.8, 0.5]) / np.linalg.norm([0.3, -0.8, 0.5])
        room = replace(room, world=World(), lights=(SunLight("sun", toward, np.full(3, 3.0)),))
        expected = 3.0 * -toward[1]
    else:  # a hole of area A in a plane under a sky of radiance 1: pi A
        expected = np.pi
    plain = [entering(room, 100_000, seed) for seed in range(3)]
    through = [entering(replace(room, portals=(portal,)), 100_000, seed) for seed in range(3)]
    for power, _ in through:
        assert power == pytest.approx(expected, rel=0.015)
    assert np.mean([p for p, _ in plain]) == pytest.approx(expected, rel=0.06)  # few photons: noisy, not biased
    assert min(n for _, n in through) > 8 * max(n for _, n in plain)  # the world: 25.5k against 720-760


def test_a_portal_filling_a_whole_outer_wall_is_used_and_one_outside_the_scene_is_named():
    # The front wall's full face: its corners are the room's, on the scene's bounding sphere up to rounding
    # (a strict test left it out). The photons the wall stops still carry the light through its window alone.
    room, window = window_room()
    L, _, H = ROOM
    wall = replace(window, name="wall", position=np.array([L / 2, 0.0, H / 2]) - room.origin_world, size_u=L, size_v=H)
    far = replace(window, name="far", position=window.position - [0.0, 2.0, 0.0])  # 2 m out: past the sphere
    assert unused_portals(replace(room, portals=(wall, far, window))) == ["far"]
    through = [entering(replace(room, portals=(wall,)), 100_000, seed)[0] for seed in range(3)]
    assert np.mean(through) == pytest.approx(np.pi, rel=0.03)
    settings = preset("PREVIEW", photons=20_000, threads=1)
    counters = bake(replace(room, portals=(far, window)), settings).stats["counters"]
    assert counters["photon_portals"] == 1  # the far one is not used


def test_portal_switch_off_ignores_the_portal():
    room, portal = window_room()
    settings = preset("PREVIEW", photons=20_000, threads=1)
    off = replace(settings, deviations=replace(Deviations(), portal_photons=False))
    a = bake(room, off)
    b = bake(replace(room, portals=(portal,)), off)
    np.testing.assert_array_equal(a.indirect["floor"], b.indirect["floor"])
    c = bake(replace(room, portals=(portal,)), settings)
    assert c.stats["counters"]["photon_portals"] == 1 and not np.array_equal(a.indirect["floor"], c.indirect["floor"])


def test_portal_steadies_the_rooms_indirect_light():
    # The floor's indirect light from two seeds: the photons through the window make it agree more closely.
    room, portal = window_room()
    settings = preset("PREVIEW", photons=50_000, threads=1)

    def spread(scene):
        a, b = (bake(scene, replace(settings, seed=s)).indirect["floor"] for s in (0, 1))
        return float(abs(a.mean() - b.mean()) / a.mean()), float(np.sqrt(np.mean((a - b) ** 2)) / a.mean())

    plain, through = spread(room), spread(replace(room, portals=(portal,)))
    assert through[1] < 0.3 * plain[1]  # 13.5 % RMS against 130 % (100k photons)


def test_a_portal_in_blender_guides_the_bake_and_adds_no_light(blender, registered, tmp_path):
    # The room as one Blender mesh under a white world, a Cycles portal in its window: the bake reads it as
    # a portal (the photons' counters), not as a light, and warns about nothing; a second portal 2 m out from
    # the wall, outside the scene's bounds, is named in a warning (the photons cannot use it); a third filling
    # the whole wall is used.
    from addon_scenes import fast_settings
    from pdic.pdic_addon import job as job_module
    from pdic.pdic_addon.properties import to_settings

    room, window = window_room()
    tris = (room.geometry.positions + room.origin_world).reshape(-1, 3)
    mesh = blender.data.meshes.new("Room")
    mesh.from_pydata(tris.tolist(), [], [(3 * i, 3 * i + 1, 3 * i + 2) for i in range(len(tris) // 3)])
    blender.context.scene.collection.objects.link(blender.data.objects.new("Room", mesh))
    world = blender.data.worlds.new("Sky")
    world.color = (1.0, 1.0, 1.0)
    blender.context.scene.world = world
    portal = blender.data.lights.new("Window", "AREA")
    portal.shape, portal.size, portal.size_y, portal.energy = "RECTANGLE", window.size_u, window.size_v, 1000.0
    portal.cycles.is_portal = True
    ob = blender.data.objects.new("Window", portal)
    ob.location = tuple(window.position + room.origin_world)
    ob.rotation_euler = (np.pi / 2, 0.0, 0.0)  # it faces along its -Z: into the room (+y)
    blender.context.scene.collection.objects.link(ob)
    far = blender.data.objects.new("Far Window", portal)  # 2 m out from the wall: outside the scene's bounds
    far.location = tuple(window.position + room.origin_world - [0.0, 2.0, 0.0])
    far.rotation_euler = ob.rotation_euler
    blender.context.scene.collection.objects.link(far)
    # The front wall's whole face: its corners are the room's, on the bounding sphere but for Blender's float32
    # matrix (cos(pi/2) = -4.4e-8), which puts them about 1e-8 of the radius past it.
    L, _, H = ROOM
    wall_light = blender.data.lights.new("Wall", "AREA")
    wall_light.shape, wall_light.size, wall_light.size_y = "RECTANGLE", L, H
    wall_light.cycles.is_portal = True
    wall = blender.data.objects.new("Wall", wall_light)
    wall.location, wall.rotation_euler = (L / 2, 0.0, H / 2), ob.rotation_euler
    blender.context.scene.collection.objects.link(wall)
    fast_settings(blender, 16)
    job = job_module.BakeJob(blender.context, to_settings(blender.context.scene.pdic),
                             output_folder=str(tmp_path / "maps"), cache_dir=tmp_path / "unwrap_cache")
    job.run()
    counters = job.result.stats["counters"]
    assert counters["photon_portals"] == 2 and counters["lights"] == 0  # the window's and the wall's
    assert not any("'Window'" in w or "'Wall'" in w for w in job.report.warnings)
    assert any("'Far Window'" in w and "outside" in w for w in job.report.warnings)
    assert np.isfinite(job.result.indirect["Room"]).all()
