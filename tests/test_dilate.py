"""Dilation: covered texels are untouched, each iteration adds one ring of neighbour means."""
from __future__ import annotations

import numpy as np
import pytest

from pdic.core.dilate import dilate


def test_covered_texels_keep_their_values(rng):
    image = rng.random((16, 16, 3)).astype(np.float32)
    coverage = rng.random((16, 16)) < 0.3
    out, cov = dilate(image, coverage, 3)
    assert np.array_equal(out[coverage], image[coverage])
    assert np.all(cov[coverage])


def test_each_iteration_fills_one_ring():
    image = np.zeros((9, 9, 1), np.float32)
    coverage = np.zeros((9, 9), bool)
    image[4, 4] = 2.0
    coverage[4, 4] = True
    for k in range(1, 4):
        out, cov = dilate(image, coverage, k)
        y, x = np.nonzero(cov)
        assert cov.sum() == (2 * k + 1) ** 2
        assert max(np.abs(y - 4).max(), np.abs(x - 4).max()) == k
        assert np.all(out[cov] == 2.0)


def test_filled_texel_is_the_mean_of_covered_neighbours():
    image = np.zeros((3, 3, 2), np.float32)
    coverage = np.zeros((3, 3), bool)
    image[0, 0] = [1.0, 10.0]
    image[0, 2] = [3.0, 20.0]
    coverage[0, 0] = coverage[0, 2] = True
    out, cov = dilate(image, coverage, 1)
    assert np.allclose(out[0, 1], [2.0, 15.0])
    assert np.allclose(out[1, 1], [2.0, 15.0])
    assert np.allclose(out[1, 0], [1.0, 10.0])
    assert not cov[2].any()


def test_zero_iterations_and_empty_coverage_change_nothing(rng):
    image = rng.random((5, 5, 3)).astype(np.float32)
    coverage = rng.random((5, 5)) < 0.5
    out, cov = dilate(image, coverage, 0)
    assert np.array_equal(out, image) and np.array_equal(cov, coverage)
    out, cov = dilate(image, np.zeros((5, 5), bool), 4)
    assert not cov.any()


def test_shape_mismatch_is_rejected():
    with pytest.raises(ValueError, match="coverage"):
        dilate(np.zeros((4, 4, 3), np.float32), np.zeros((4, 5), bool), 1)
