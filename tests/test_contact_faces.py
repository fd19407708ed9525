"""Faces that touch face to face get no light (deviation: contact-faces): a box's bottom on a ground plane
under the sky; a sheet of two open faces back to back stays lit on both sides. Nor do faces under a sheet
nearer than the rays' offset (deviation: under-sheets)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from pdic.core.contact import ContactFaces, touching_planes
from pdic.core.pipeline import bake
from pdic.core.rays import RayCaster
from pdic.core.scene import World
from pdic.core.settings import Deviations, preset

from scenes import bake_samples, box_on_ground, quad, quad_scene

FINAL = preset("FINAL", threads=2)
X, Y, Z = (np.eye(3)[i] for i in range(3))
GROUND = quad(np.array([-2.0, -2.0, 0.0]), 4 * X, 4 * Y)
"""A 4 x 4 m ground facing up (two triangles)."""


def test_a_box_bottom_on_the_ground_gets_no_light_and_a_two_sided_sheet_keeps_both_sides():
    """Without the rule the bottom's rays start under the ground plane and see the sky below the horizon
    (E/pi about 0.5); Cycles' start on the bottom and meet the ground. The sheet's two faces touch the
    same way but bound no solid (a ray into a face's back meets no back face): one surface seen from two
    sides, both see the sky as before, to the bit. The ground under the box is not the skin of a solid
    either: texel validity's vote buries it (its rays meet the box's inside)."""
    scene = box_on_ground()
    on = bake(scene, FINAL)
    off = bake(scene, replace(FINAL, deviations=Deviations(contact_faces=False, under_sheets=False)))
    inside = on.centre_inside["bottom"]
    points = bake_samples(scene)
    bottom = points.target == [t.name for t in scene.targets].index("bottom")
    assert on.stats["counters"]["texel_samples_in_contact"] == bottom.sum() >= 4 * inside.sum()  # the bottom's alone
    assert off.stats["counters"]["texel_samples_in_contact"] == 0 and "contact_rays" not in off.stats["counters"]
    assert on.stats["counters"]["contact_rays"] >= on.stats["counters"]["texel_samples_in_contact"]
    assert off.direct["bottom"][inside].mean() > 0.2  # the sky below the ground, through the offset
    assert np.all(on.direct["bottom"][inside] == 0) and np.all(on.indirect["bottom"][inside] == 0)
    assert np.all(on.as_cycles("bottom")[inside] == 0)
    for name in ("sheet_front", "sheet_back", "top"):
        lit = on.centre_inside[name]
        assert on.direct[name][lit].mean() > 0.2
        np.testing.assert_array_equal(on.direct[name], off.direct[name])
    # The ground under the box is inside it either way; beside it the sky lights it.
    ground = on.direct["ground"] + on.indirect["ground"]
    assert ground[on.centre_inside["ground"]].max() > 0.5


def test_only_faces_sharing_a_plane_facing_the_other_way_are_asked():
    """A face 3 ray offsets above the ground is a real gap, not contact; one within an offset touches, and
    so does the ground's reversed copy; a face of the same facing in the same plane is a duplicate. Of the
    samples that touch, only those on a solid's skin count: the box's bottom, not the ground, nor a lone
    face (an open sheet)."""
    caster = RayCaster(np.concatenate([GROUND, quad(np.zeros(3), Y, X)]))
    eps = caster.epsilon

    def asked(face):
        positions = np.concatenate([GROUND, face])
        _, candidate = touching_planes(positions, RayCaster(positions, caster.extent).face_normals, 2 * eps)
        return candidate

    assert asked(quad(np.zeros(3), Y, X)).all()  # a bottom in the ground's plane, facing down
    assert asked(quad(0.5 * eps * Z, Y, X)).all()  # half an offset above it
    assert not asked(quad(6 * eps * Z, Y, X)).any()  # three offsets (six epsilons) above: a gap
    assert not asked(quad(np.zeros(3), X, Y)).any()  # facing up: a duplicate in place
    assert asked(quad(np.array([-2.0, -2.0, 0.0]), 4 * Y, 4 * X)).all()  # the ground's reversed copy
    # Samples: on the bottom of a closed box, on the ground under and beside it; on a lone face's bottom.
    box = [quad(np.zeros(3), Y, X), quad(Z, X, Y), quad(np.zeros(3), X, Z), quad(Y, Z, X), quad(np.zeros(3), Z, Y),
           quad(X, Y, Z)]
    positions = np.concatenate([GROUND, *box])
    faces = ContactFaces(positions, RayCaster(positions))
    p = np.array([[0.5, 0.5, 0.0], [0.5, 0.5, 0.0], [1.5, 1.5, 0.0]])
    assert faces.samples(p, np.array([2, 0, 0])).tolist() == [True, False, False]
    # the touch test for the three, the skin test for the two that touch, the sheet test for the three
    assert faces.rays_cast == 3 + 2 + 3
    lone = np.concatenate([GROUND, quad(np.zeros(3), Y, X)])
    assert not ContactFaces(lone, RayCaster(lone)).samples(p[:1], np.array([2])).any()
    # A slab on the box: the box's top touches the slab's bottom, and the skin test's ray from the top
    # down through the box meets the box's bottom and the ground together, a back and a front face.
    slab = [quad(Z, Y, X), quad(1.2 * Z, X, Y), quad(Z, X, 0.2 * Z), quad(Y + Z, 0.2 * Z, X), quad(Z, 0.2 * Z, Y),
            quad(X + Z, Y, 0.2 * Z)]
    stacked = np.concatenate([GROUND, *box, *slab])
    faces = ContactFaces(stacked, RayCaster(stacked))
    top, slab_bottom = 2 + 2 * 1, 2 + 2 * 6  # the box's top face, the slab's bottom face (first triangles)
    on_top = np.array([[0.3, 0.6, 1.0], [0.3, 0.6, 1.0], [0.5, 0.5, 0.0]])
    assert faces.samples(on_top, np.array([top, slab_bottom, 2])).tolist() == [True, True, True]


def _ground_and(sheet):
    """A 4 x 4 m ground (facing up, triangles 0-1) and one more quad (triangles 2-3), with their RayCaster."""
    positions = np.concatenate([GROUND, sheet])
    return positions, RayCaster(positions)


def test_a_sheet_nearer_than_the_rays_offset_covers_what_lies_under_it_whichever_way_it_faces():
    """Half an offset over the ground a 1 m sheet facing up (a decal) or down covers the ground under it,
    not beside it. A copy in place (the same plane), a sheet three offsets up (the samples' own rays meet it)
    or one tilted 30 degrees across the ground's plane (an intersection beside the sample) does not, nor
    one that lets light through."""
    _, caster = _ground_and(quad(np.zeros(3), X, Y))
    eps = caster.epsilon
    under, beside = [0.5, 0.5, 0.0], [1.5, 1.5, 0.0]
    p, ground = np.array([under, beside]), np.array([0, 1])

    def covered(sheet):
        positions, caster = _ground_and(sheet)
        return ContactFaces(positions, caster, touch=False).under_sheet(p, ground).tolist()

    assert covered(quad(0.5 * eps * Z, X, Y)) == [True, False]
    assert covered(quad(0.5 * eps * Z, Y, X)) == [True, False]  # facing down
    # tilted 1.1 degrees about x, half an offset up at the sample's y (it crosses the ground's plane nearby)
    assert covered(quad((0.5 * eps - 0.01) * Z, X, Y + 0.02 * Z)) == [True, False]
    assert covered(quad(np.zeros(3), X, Y)) == [False, False]  # a copy in place
    assert covered(quad(3 * eps * Z, X, Y)) == [False, False]
    tilted = quad(np.array([0.5 - 0.25 * eps, -1.0, 0.0]), 2 * Y, np.array([np.cos(np.pi / 6), 0.0, np.sin(np.pi / 6)]))
    assert covered(tilted) == [False, False]
    positions, caster = _ground_and(quad(0.5 * eps * Z, X, Y))
    assert ContactFaces(positions, caster, sheets=False).under_sheet(p, ground).tolist() == [False, False]
    glass = RayCaster(positions, transmission=np.array([0.0, 0.0, 1.0, 1.0]))  # light passes it (Cycles' shadows)
    assert ContactFaces(positions, glass).under_sheet(p, ground).tolist() == [False, False]


def test_the_ground_under_a_decal_bakes_black_as_in_cycles_and_the_decal_is_lit():
    """A 1 m decal half a ray offset over a 4 m ground under a white sky: the ground's texels under it get
    no direct or indirect light (Cycles' rays meet the decal's back), the decal and the open ground are lit.
    Off, the ground under it is lit as the open ground through the offset."""
    eps = _ground_and(quad(np.zeros(3), X, Y))[1].epsilon
    scene = replace(quad_scene([GROUND, quad(0.5 * eps * Z, X, Y)],
                               {"ground": (0, 16), "decal": (1, 8)}, []), world=World(np.full(3, 1.0)))
    on = bake(scene, FINAL)
    off = bake(scene, replace(FINAL, deviations=Deviations(under_sheets=False)))
    ground = on.centre_inside["ground"]
    centres = (np.stack(np.meshgrid(np.arange(16), np.arange(16)), axis=-1) + 0.5) / 16 * 4 - 2  # (row, col) -> x, y
    hidden = ground & np.all((centres > 0.125) & (centres < 0.875), axis=-1)  # wholly under the decal
    assert hidden.sum() == 4 and on.stats["counters"]["texel_samples_under_sheet"] >= 16
    assert np.all(on.as_cycles("ground")[hidden] == 0)
    assert off.as_cycles("ground")[hidden].mean() > 0.5
    assert off.stats["counters"]["texel_samples_under_sheet"] == 0
    open_ground = ground & np.all((centres < -0.5) | (centres > 1.5), axis=-1)
    for result in (on, off):
        assert result.as_cycles("ground")[open_ground].mean() > 0.5
        assert result.as_cycles("decal")[result.centre_inside["decal"]].mean() > 0.5
