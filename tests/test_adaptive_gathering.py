"""Adaptive gathering (deviation: adaptive-gathering): a record whose E_k is noisy by its own cells
gathers again with real rays and averages; one gather is passed through unchanged."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from pdic.core.constants import GATHER_DARK, GATHER_ERROR
from pdic.core.pipeline import bake
from pdic.core.refinement import COUNTERS, Gathers
from pdic.core.settings import Deviations, preset

from scenes import lamp_box, seed_difference


def _gather(E, R, error, inside=None):
    """A refine_batch-like result for len(E) records with gradients E x 1 and counters of 1."""
    E = np.asarray(E, float)
    return {"E": E, "grad_r": E[:, :, None] * np.ones(3), "grad_t": -E[:, :, None] * np.ones(3),
            "R": np.asarray(R, float), "standard_error": np.asarray(error, float),
            "inside": np.zeros(len(E), bool) if inside is None else np.asarray(inside),
            **{key: 1 for key in COUNTERS if key != "refine_extra_gathers"}}


def test_one_gather_is_passed_through_bit_for_bit():
    rng = np.random.default_rng(1)
    E, R = rng.random((5, 3)), rng.random(5) + 0.1
    gathers, counters = Gathers(5), dict.fromkeys(COUNTERS, 0)
    gathers.add(slice(0, 5), _gather(E, R, np.zeros(5)), counters)
    mean_E, grad_r, grad_t, mean_R = gathers.means()
    assert np.array_equal(mean_E, E) and np.array_equal(mean_R, R)
    assert np.array_equal(grad_r, E[:, :, None] * np.ones(3)) and np.array_equal(grad_t, -grad_r)
    assert counters["refine_rays_cast"] == 1


def test_later_gathers_average_e_and_gradients_and_take_the_harmonic_mean_of_r():
    gathers, counters = Gathers(3), dict.fromkeys(COUNTERS, 0)
    gathers.add(slice(0, 3), _gather(np.full((3, 3), 1.0), [1.0, 2.0, np.inf], np.zeros(3)), counters)
    gathers.add(np.array([0, 2]), _gather(np.full((2, 3), 3.0), [3.0, np.inf], np.zeros(2)), counters)
    E, grad_r, _, R = gathers.means()
    np.testing.assert_allclose(E[:, 0], [2.0, 1.0, 2.0])
    np.testing.assert_allclose(grad_r[:, 0, 0], [2.0, 1.0, 2.0])
    np.testing.assert_allclose(R, [1.5, 2.0, np.inf])  # 2 / (1/1 + 1/3); misses stay misses


def test_noisy_records_are_those_above_the_error_target_and_a_dark_record_counts_against_the_floor():
    E = np.array([[1.0] * 3, [1.0] * 3, [1.0] * 3, [0.01] * 3])
    error = np.array([0.5 * GATHER_ERROR, 2 * GATHER_ERROR, 0.0, 0.5 * GATHER_ERROR * GATHER_DARK])
    gathers = Gathers(4)
    gathers.add(slice(0, 4), _gather(E, np.ones(4), error), dict.fromkeys(COUNTERS, 0))
    # record 3: 50 % noise on 1 % of the light is below the floor GATHER_DARK x mean E
    assert gathers.noisy().tolist() == [1]
    # a second gather as noisy halves the mean's variance: sqrt(2) / 2 x 2 = 1.41 x the target
    gathers.add(np.array([1]), _gather(E[1:2], [1.0], error[1:2]), dict.fromkeys(COUNTERS, 0))
    assert gathers.noisy().tolist() == [1]


def test_a_record_any_gather_finds_inside_geometry_stays_black():
    gathers = Gathers(2)
    gathers.add(slice(0, 2), _gather(np.ones((2, 3)), np.ones(2), np.ones(2)), dict.fromkeys(COUNTERS, 0))
    gathers.add(np.array([1]), _gather(np.zeros((1, 3)), [1.0], [0.0], inside=[True]), dict.fromkeys(COUNTERS, 0))
    E, grad_r, grad_t, _ = gathers.means()
    assert E[0].tolist() == [1.0] * 3 and not E[1].any() and not grad_r[1].any() and not grad_t[1].any()


FINAL = preset("FINAL", photons=20_000, max_bounces=3, threads=1, hemisphere_theta=6, hemisphere_phi=12)


def _indirect(seed: int, adaptive: bool) -> dict:
    scene = lamp_box(24)
    # thin-coverage off: its hole records' lookups average the records' noise too (0.974x with it on)
    result = bake(scene, replace(FINAL, seed=seed, deviations=Deviations(adaptive_gathering=adaptive,
                                                                          thin_coverage=False)))
    assert (result.stats["counters"]["refine_extra_gathers"] > 0) == adaptive
    return result.indirect


def test_gathering_noisy_records_again_brings_two_seeds_closer():
    # A lamp under a box's ceiling: records see its bright spot through a coarse 72-cell hemisphere.
    def difference(adaptive):
        return seed_difference(_indirect(1, adaptive), _indirect(2, adaptive))

    assert difference(True) < 0.96 * difference(False)


def test_the_stages_a_bake_reports_name_each_round_of_gathering_once_and_whose_texels_they_are():
    """The progress a user watches: noisy records' later gathers are named after the stage they belong to,
    and the hole records' rounds after themselves, so labels never pile up one round's name on the last's;
    the stages run once per object name it, the passes shared by all objects do not."""
    from pdic.core.executor import Progress

    stages = []
    bake(lamp_box(24), FINAL, Progress(lambda stage, fraction, eta: stages.append(stage)))
    again = [stage for stage in stages if "gather again" in stage]
    assert any(stage.startswith("Pass 3: refining records: ") for stage in again)
    assert any(stage.startswith("floor (1 of 2): Hole records, round 1: gathering at ") for stage in again)
    assert all(stage.count("gather again") == 1 for stage in again), sorted(set(again))
    for name in ("floor (1 of 2)", "back (2 of 2)"):
        assert f"{name}: Texel validity" in stages and f"{name}: Interpolating the cache at texels" in stages
        assert any(stage.startswith(f"{name}: Hole records, round 1: placing records at ") for stage in stages)
    assert not any(stage.startswith(("floor", "back")) for stage in stages if "Pass" in stage)
