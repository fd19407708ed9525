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
    # Walls lit on their backs are open space (tests/test_back_lit_faces.py): no sample is voted inside.
    assert counters["texel_samples_inside_geometry"] == 0
    assert abs(outward.mean() / inward.mean() - 1) < 0.1
    assert (outward > 0.25 * inward.mean()).all()  # no black texel


def test_without_photon_evidence_the_floor_before_outward_walls_goes_black():
    blacked, counters = _floor("PREVIEW", True, photon_evidence=False)
    assert counters["texel_samples_photon_evidence"] == 0
    assert counters["texel_samples_inside_geometry"] > 0
    assert (blacked == 0).any()


def test_photons_that_landed_nearby_prove_light_reaches_a_point_and_none_land_under_a_slab():
    """The evidence itself (``reached_by_photons``): the vote's other half, for faces lit on both sides."""
    import numpy as np

    from pdic.core.density import PhotonDensity
    from pdic.core.photons import trace_photons
    from pdic.core.rays import RayCaster
    from pdic.core.validity import overrule_by_photons

    from scenes import lit, quad

    slab = [quad([0.2, 0.2, 0.01], [0.3, 0, 0], [0, 0.3, 0]), quad([0.2, 0.2, 0.01], [0, 0.3, 0], [0.3, 0, 0])]
    tris = np.concatenate(box_faces() + slab)  # a two-sided slab 1 cm over the floor
    caster = RayCaster(tris)
    photons, _ = trace_photons(lit(tris, BOX_LAMP), caster, 20_000, 4, seed=2)
    density = PhotonDensity(photons)
    p = np.array([[0.7, 0.7, 0.0], [0.35, 0.35, 0.0]])  # the open floor, the floor under the slab's middle
    n = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    inside = np.ones(2, bool)  # as if the back-face vote had put both inside
    assert overrule_by_photons(inside, caster, density, p, n, R_min=0.02) == 1
    assert inside.tolist() == [False, True]
