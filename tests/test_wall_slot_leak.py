"""The closed slot inside a hollow wall stays dark when thin bars stand a few cm in front of the wall (issue #11).

Core only. The generated cathedral's south wall is two faces 0.8 m apart whose normals point into
the slot between them (a flipped wall): the faces bake the slot's side, which no light reaches
(Cycles: 0). Its window tracery stands 2-4 cm in front of the wall on the lit side, and the records
on the bars' backs face the wall, the way the slot side of the wall faces. Pass 3's hit-grid cells
on the slot side read those records without the record-visibility test a texel's lookup makes,
through the wall: 3,032 texels of the wall's outside face got light (up to the map's mean), and
here the slot's far face got E/pi 1.12 on every texel (0 with the test). With the slot's floor
continuing the room's (a floor running on under a wall), the floor's records also reached past the
wall's foot through their wall polygon's wedge (docs/DEVIATIONS.md wall-sectors).
"""
from __future__ import annotations

import numpy as np

from pdic.core import pipeline
from pdic.core.scene import BakeTarget, Materials, PointLight, Scene, recentre
from pdic.core.settings import Deviations, preset

from scenes import geometry, quad

RES = 16
UV = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)


def _bar(x, y0, y1, z0, z1, half=0.03) -> np.ndarray:
    """(12, 3, 3) a closed box (normals outward) from x - half to x + half."""
    X, Y, Z = 2 * half, y1 - y0, z1 - z0
    x0 = x - half
    return np.concatenate([
        quad([x0, y0, z0], [0, Y, 0], [X, 0, 0]), quad([x0, y0, z1], [X, 0, 0], [0, Y, 0]),
        quad([x0, y0, z0], [X, 0, 0], [0, 0, Z]), quad([x0, y1, z0], [0, 0, Z], [X, 0, 0]),
        quad([x0, y0, z0], [0, 0, Z], [0, Y, 0]), quad([x0 + X, y0, z0], [0, Y, 0], [0, 0, Z]),
    ])


def _scene(inset: bool = True) -> Scene:
    """A 4 x 4 x 3 m room lit by a point light; its wall at y = 0 faces away from it (normal -y) into a
    closed 0.8 m slot whose other faces point into the slot too; three bars 3-9 cm in front of the
    wall in the room. Targets: the slot's far face ("Outer", y = -0.8), the shared wall ("Wall") and
    the slot's floor ("SlotFloor").

    inset : the slot is 3 x 2.2 m, off the room's floor, ceiling and side walls (the rest of the wall
        faces the black world); else it spans the whole wall and its floor continues the room's, as
        a floor running on under a wall into the next room does.
    """
    X, Y, Z, S = 4.0, 4.0, 3.0, 0.8
    room = [
        quad([-2, 0, 0], [X, 0, 0], [0, Y, 0]),  # floor, up
        quad([-2, 0, Z], [0, Y, 0], [X, 0, 0]),  # ceiling, down
        quad([-2, Y, 0], [X, 0, 0], [0, 0, Z]),  # back wall, -y
        quad([-2, 0, 0], [0, Y, 0], [0, 0, Z]),  # left, +x
        quad([2, 0, 0], [0, 0, Z], [0, Y, 0]),  # right, -x
    ]
    x0, x1, z0, z1 = (-1.5, 1.5, 0.5, 2.7) if inset else (-2.0, 2.0, 0.0, Z)
    W, H = x1 - x0, z1 - z0
    slot = [
        quad([-2, 0, 0], [X, 0, 0], [0, 0, Z]),  # the shared wall: normal -y, into the slot
        quad([x0, -S, z0], [0, 0, H], [W, 0, 0]),  # the slot's far face: +y
        quad([x0, -S, z0], [W, 0, 0], [0, S, 0]),  # slot floor, up
        quad([x0, -S, z1], [0, S, 0], [W, 0, 0]),  # slot ceiling, down
        quad([x0, -S, z0], [0, S, 0], [0, 0, H]),  # slot ends, inward
        quad([x1, -S, z0], [0, 0, H], [0, S, 0]),
    ]
    faces = room + slot
    tris = np.concatenate(faces + [_bar(x, 0.03, 0.09, 1.0, 2.5) for x in (-1.0, 0.0, 1.0)])
    local, origin = recentre(tris)
    first = {"Wall": 2 * len(room), "Outer": 2 * len(room) + 2, "SlotFloor": 2 * len(room) + 4}
    target = np.full(len(tris), -1, np.int32)
    for k, i in enumerate(first.values()):
        target[i:i + 2] = k
    targets = tuple(BakeTarget(name, np.array([i, i + 1]), UV, RES, RES) for name, i in first.items())
    light = PointLight("Lamp", np.array([0.0, 2.0, 2.5]) - origin, np.full(3, 500.0))
    return Scene(geometry(local, target=target), Materials.default(1), lights=(light,), targets=targets,
                 origin_world=origin)


def _bake(deviations: Deviations = Deviations(), inset: bool = True):
    return pipeline.bake(_scene(inset), preset("FINAL", photons=60_000, default_resolution=RES, threads=1,
                                               deviations=deviations))


def test_the_slot_inside_a_wall_gets_no_light():
    result = _bake()
    assert float(result.cache.E.max()) > 1.0  # the room is lit, the bars' backs included
    for name in ("Wall", "Outer", "SlotFloor"):
        assert float(result.lightmaps[name][..., :3].max()) == 0.0, name


def test_a_floor_running_on_under_the_wall_carries_no_light_past_its_foot():
    """The room's floor records stop at the wall's foot: past a wall met by one sector ray only, a
    point between the polygons whose missed rays stand at the zone's radius and far away counts only
    if the record sees it (before: the slot's floor E/pi up to 1.92 on 217 of its 256 texels, and
    the slot's hole records spread that to its walls)."""
    result = _bake(inset=False)
    for name in ("Wall", "Outer", "SlotFloor"):
        assert float(result.lightmaps[name][..., :3].max()) == 0.0, name


def test_without_record_visibility_the_bars_light_the_slot():
    """The switch is what keeps the slot dark: off, the bars' records reach through the wall."""
    leaky = _bake(Deviations(record_visibility=False))
    assert float(leaky.lightmaps["Outer"][..., :3].max()) > 0.01
