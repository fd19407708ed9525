"""Gradient limiting (deviation: gradient-limiting): a record's translational gradient may move E_k by at
most GRADIENT_LIMIT of it across its zone; the rotational one by E_k per radian."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

import pdic.core.gather_cells as gather_cells
from pdic.core.constants import GRADIENT_LIMIT
from pdic.core.gather_cells import limit_gradients
from pdic.core.pipeline import bake
from pdic.core.settings import Deviations, preset

from scenes import lamp_box, seed_difference


def test_gradients_past_the_limit_are_scaled_to_it_and_the_rest_kept():
    E = np.array([[2.0, 1.0, 0.0], [4.0, 4.0, 4.0]])
    zone = np.array([0.5, 2.0])
    grad_t = np.zeros((2, 3, 3))
    grad_t[0, 0] = [3.0, 4.0, 0.0]  # |5| > 0.3 x 2 / 0.5 = 1.2: scaled to length 1.2, direction kept
    grad_t[0, 1] = [0.0, 0.3, 0.0]  # below 0.3 x 1 / 0.5 = 0.6: kept
    grad_t[0, 2] = [0.0, 0.0, 1e-3]  # a black channel allows no gradient
    grad_t[1] = [0.35, 0.0, 0.0]  # below 0.3 x 4 / 2 = 0.6: kept
    grad_r = np.zeros((2, 3, 3))
    grad_r[0, 0] = [0.0, 6.0, 0.0]  # > E = 2: scaled to 2
    grad_r[1, 2] = [1.0, 0.0, 0.0]  # < 4: kept
    t, r = limit_gradients(E, grad_t, grad_r, zone)
    assert GRADIENT_LIMIT == 0.3
    np.testing.assert_allclose(t[0, 0], [0.72, 0.96, 0.0])
    np.testing.assert_array_equal(t[0, 1], grad_t[0, 1])
    np.testing.assert_array_equal(t[0, 2], 0.0)
    np.testing.assert_array_equal(t[1], grad_t[1])
    np.testing.assert_allclose(r[0, 0], [0.0, 2.0, 0.0])
    np.testing.assert_array_equal(r[1], grad_r[1])
    assert np.isfinite(t).all() and np.isfinite(r).all()


# thin-coverage off: its hole records' lookups average the gradients' noise too (0.978x with it on)
FINAL = preset("FINAL", photons=20_000, max_bounces=3, threads=1, hemisphere_theta=6, hemisphere_phi=12,
               deviations=Deviations(thin_coverage=False))


def _seed_difference() -> float:
    return seed_difference(*(bake(lamp_box(24), replace(FINAL, seed=seed)).indirect for seed in (1, 2)))


def test_the_tighter_limit_brings_two_seeds_closer(monkeypatch):
    # A lamp under a box's ceiling, a coarse 72-cell hemisphere (0.877x measured).
    tight = _seed_difference()
    monkeypatch.setattr(gather_cells, "GRADIENT_LIMIT", 1.0)
    assert tight < 0.95 * _seed_difference()
