"""Faces lit from behind are open space (deviation: photon-evidence, docs/DEVIATIONS.md).

Texel validity's back-face vote calls a sample inside closed geometry when its rays mostly meet
faces from behind; a wall whose normals point the wrong way is met from behind from the room it
bounds. Photon evidence overrules the vote where a photon landed near the sample, which a small
surface may never catch. A triangle more photons reached on its back than on its front is lit
from behind, so its normals are flipped and meeting its back says nothing about being inside; a
front-lit face that a few photons reached from behind (a banner, a crack) still counts.
"""
from __future__ import annotations

import numpy as np

from pdic.core.density import PhotonDensity
from pdic.core.photons import trace_photons
from pdic.core.pipeline import bake
from pdic.core.rays import RayCaster
from pdic.core.settings import Deviations, preset
from pdic.core.validity import inside_geometry

from scenes import BOX_LAMP, box_faces, lit, quad, quad_scene

PLATE = quad([0.7, 0.475, 0.475], [0, 0.05, 0], [0, 0, 0.05])
"""A 5 cm plate at the unit box's centre height, facing +x (the right wall, 30 cm away)."""


def _room(walls_face_out: bool, *extra):
    faces = box_faces()
    if walls_face_out:
        faces = [faces[0]] + [face[:, ::-1] for face in faces[1:]]
    return faces + list(extra)


def test_flipped_walls_are_lit_from_behind_and_a_banner_lit_on_both_sides_is_not():
    banner = quad([0.3, 0.2, 0.1], [0, 0.6, 0], [0, 0, 0.5])  # facing +x, toward the lamp at x = 0.5
    tris = np.concatenate(_room(True, banner))
    scene = lit(tris, BOX_LAMP)
    caster = RayCaster(tris)
    photons, _ = trace_photons(scene, caster, 20_000, 4, seed=1)
    density = PhotonDensity(photons)
    front, back = density.photons_per_side(caster.face_normals)
    lit_back, back_lit = density.lit_back_faces(caster.face_normals), density.back_lit_faces(caster.face_normals)
    assert not back_lit[:2].any() and front[:2].min() > 100  # the floor faces the room
    assert back_lit[2:12].all()  # walls and ceiling face out: their photons arrive on their backs
    assert front[2:12].max() == 0
    assert lit_back[12:].all() and back[12:].min() > 0  # the banner's back catches light bounced past it
    assert not back_lit[12:].any() and (front[12:] > 1.5 * back[12:]).all()


def test_a_floor_sample_before_flipped_walls_is_outside_when_their_backs_are_open():
    tris = np.concatenate(_room(True))
    caster = RayCaster(tris)
    p, n = np.array([[0.5, 0.5, 0.0]]), np.array([[0.0, 0.0, 1.0]])
    inside, _, _ = inside_geometry(caster, caster.face_normals, p, n, np.random.default_rng(0))
    assert inside.all()  # every ray meets a wall or the ceiling from behind
    open_back = np.ones(len(tris), bool)
    inside, _, _ = inside_geometry(caster, caster.face_normals, p, n, np.random.default_rng(0), open_back=open_back)
    assert not inside.any()


def _plate(walls_face_out: bool, **deviations):
    scene = quad_scene(_room(walls_face_out, PLATE), {"plate": (6, 8)}, [BOX_LAMP])
    settings = preset("FINAL", photons=1_500, max_bounces=4, threads=1, hemisphere_theta=8, hemisphere_phi=16,
                      deviations=Deviations(**deviations))
    result = bake(scene, settings)
    photons = result.photons
    on_plate = (np.isin(photons.triangle, [12, 13]) & (photons.n[:, 0] > 0)).sum()  # on its front
    return result.indirect["plate"][result.centre_inside["plate"]], on_plate


def test_a_small_plate_facing_flipped_walls_is_lit_as_before_walls_facing_in():
    inward, _ = _plate(False)
    outward, on_plate = _plate(True)
    assert on_plate == 0  # no photon on its front to overrule the back-face vote
    assert inward.mean() > 0.2
    assert (outward > 0.5 * inward.mean()).all()  # black on every texel before (all samples voted inside)
    assert abs(outward.mean() / inward.mean() - 1) < 0.15
