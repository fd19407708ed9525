"""Photon evidence (deviation: photon-evidence): walls whose normals point the wrong way do not black
out what they face. Cycles shades both sides of a face alike, so a room whose walls' normals point
out of it is lit like one whose normals point in; the back-face votes alone called its floor inside
geometry (the cathedral's south wall and apse: capitals and columns facing them came out black)."""
from __future__ import annotations

import pytest

from pdic.core.pipeline import bake
from pdic.core.settings import Deviations, preset

from scenes import BOX_LAMP, box_faces, quad_scene



def _room(walls_face_out: bool):
    """The unit box with the lamp under its ceiling; the floor (the target) faces up either way."""
    faces = box_faces()
    if walls_face_out:
        faces = [faces[0]] + [face[:, ::-1] for face in faces[1:]]
    return quad_scene(faces, {"floor": (0, 16)}, [BOX_LAMP])


def _floor(quality: str, walls_face_out: bool, **deviations):
    settings = preset(quality, photons=40_000, max_bounces=4, threads=1, hemisphere_theta=8, hemisphere_phi=16,
                      deviations=Deviations(**deviations))
    result = bake(_room(walls_face_out), settings)
    return result.indirect["floor"][result.centre_inside["floor"]], result.stats["counters"]


@pytest.mark.parametrize("quality", ["PREVIEW", "FINAL"])
def test_a_room_whose_walls_face_out_lights_its_floor_as_one_whose_walls_face_in(quality):
    inward, _ = _floor(quality, False)
    outward, counters = _floor(quality, True)
    assert inward.mean() > 0.5
    assert counters["texel_samples_photon_evidence"] > 0  # the votes put floor samples inside; photons overruled
    assert abs(outward.mean() / inward.mean() - 1) < 0.1
    assert (outward > 0.25 * inward.mean()).all()  # no black texel


def test_without_photon_evidence_the_floor_before_outward_walls_goes_black():
    blacked, counters = _floor("PREVIEW", True, photon_evidence=False)
    assert counters["texel_samples_photon_evidence"] == 0
    assert counters["texel_samples_inside_geometry"] > 0
    assert (blacked == 0).any()
