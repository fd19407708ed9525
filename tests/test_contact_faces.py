"""Faces that touch face to face get no light (deviation: contact-faces): a box's bottom on a ground plane
under the sky; a sheet made two-sided by a reversed copy of itself stays lit on both sides."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from pdic.core.contact import ContactFaces, touching_planes
from pdic.core.pipeline import bake
from pdic.core.rays import RayCaster
from pdic.core.scene import World
from pdic.core.settings import Deviations, preset

from scenes import quad, quad_scene

FINAL = preset("FINAL", threads=2)
X, Y, Z = (np.eye(3)[i] for i in range(3))


def _box_on_ground(res: int = 16):
    """A 4 x 4 m ground plane (one face, up), a closed unit box standing on it (its bottom face down, in
    the ground's plane) and a 1 x 1 m upright sheet made of two reversed copies, under a white sky."""
    faces = [quad(np.array([-2.0, -2.0, 0.0]), 4 * X, 4 * Y),  # 0 ground
             quad(np.zeros(3), Y, X), quad(Z, X, Y), quad(np.zeros(3), X, Z), quad(Y, Z, X),  # 1 bottom, top, front, back
             quad(np.zeros(3), Z, Y), quad(X, Y, Z),  # left, right
             quad(np.array([-1.5, 1.5, 0.0]), X, Z), quad(np.array([-1.5, 1.5, 0.0]), Z, X)]  # 7, 8 the sheet
    targets = {"ground": (0, res), "bottom": (1, res), "top": (2, res), "sheet_front": (7, res), "sheet_back": (8, res)}
    return replace(quad_scene(faces, targets, []), world=World(np.full(3, 1.0)))


def test_a_box_bottom_on_the_ground_gets_no_light_and_a_two_sided_sheet_keeps_both_sides():
    """Without the rule the bottom's rays start under the ground plane and see the sky below the horizon
    (E/pi about 0.5); Cycles' start on the bottom and meet the ground. The sheet's two faces touch the
    same way but are one surface: both sides see the sky as before, to the bit."""
    scene = _box_on_ground()
    on = bake(scene, FINAL)
    off = bake(scene, replace(FINAL, deviations=Deviations(contact_faces=False)))
    inside = on.centre_inside["bottom"]
    assert on.stats["counters"]["texel_samples_in_contact"] >= inside.sum()
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
    """A face 3 ray offsets above the ground is a real gap, not contact; one within an offset touches;
    a reversed copy is the same surface; a face of the same facing in the same plane is a duplicate."""
    ground = quad(np.array([-2.0, -2.0, 0.0]), 4 * X, 4 * Y)
    caster = RayCaster(np.concatenate([ground, quad(np.zeros(3), Y, X)]))
    eps = caster.epsilon

    def asked(face):
        positions = np.concatenate([ground, face])
        _, candidate = touching_planes(positions, RayCaster(positions, caster.extent).face_normals, 2 * eps)
        return candidate

    assert asked(quad(np.zeros(3), Y, X)).all()  # a bottom in the ground's plane, facing down
    assert asked(quad(0.5 * eps * Z, Y, X)).all()  # half an offset above it
    assert not asked(quad(6 * eps * Z, Y, X)).any()  # three offsets (six epsilons) above: a gap
    assert not asked(quad(np.zeros(3), X, Y)).any()  # facing up: a duplicate in place
    assert not asked(quad(np.array([-2.0, -2.0, 0.0]), 4 * Y, 4 * X)).any()  # the ground's reversed copy
    # Samples: on the bottom, and on the ground beside and under it.
    positions = np.concatenate([ground, quad(np.zeros(3), Y, X)])
    faces = ContactFaces(positions, RayCaster(positions))
    p = np.array([[0.5, 0.5, 0.0], [0.5, 0.5, 0.0], [1.5, 1.5, 0.0]])
    touching = faces.samples(p, np.array([2, 0, 0]))
    assert touching.tolist() == [True, True, False]
