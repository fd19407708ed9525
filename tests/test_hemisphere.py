"""Stratified hemisphere: equal-weight cells and gradients against closed forms."""
import numpy as np
import pytest

from pdic.core.hemisphere import Hemisphere


def _random_rays(H, rng, per_cell=8):
    cells = np.repeat(np.arange(H.cells), per_cell)
    w = H.sample_cells(cells, rng.random((len(cells), 2)))
    return cells, w


def _cell_means(H, cells, values):
    out = np.zeros((H.cells, values.shape[1]))
    for c in range(values.shape[1]):
        out[:, c] = np.bincount(cells, weights=values[:, c], minlength=H.cells)
    return out / np.bincount(cells, minlength=H.cells)[:, None]


def test_cells_have_equal_cosine_weight():
    H = Hemisphere(12, 24)
    rng = np.random.default_rng(1)
    # Cosine-weighted directions fall into every cell equally often.
    u = rng.random((400_000, 2))
    r = np.sqrt(u[:, 0])
    w = np.column_stack([r * np.cos(2 * np.pi * u[:, 1]), r * np.sin(2 * np.pi * u[:, 1]), np.sqrt(1 - u[:, 0])])
    counts = np.bincount(H.cell_of(w), minlength=H.cells)
    expected = len(w) / H.cells
    assert np.abs(counts - expected).max() < 5 * np.sqrt(expected)


def test_sample_cells_lands_in_its_cell():
    H = Hemisphere(7, 13)
    rng = np.random.default_rng(2)
    cells = rng.integers(0, H.cells, 10_000)
    w = H.sample_cells(cells, rng.random((10_000, 2)))
    assert np.allclose(np.linalg.norm(w, axis=1), 1.0)
    assert np.array_equal(H.cell_of(w), cells)


def test_uniform_sky_gives_pi_L():
    H = Hemisphere(10, 20)
    L = np.full((1, H.cells, 3), 2.5)
    E, g_r, g_t = H.irradiance_and_gradients(L, np.ones((1, H.cells)))
    assert np.allclose(E, np.pi * 2.5)
    assert np.allclose(g_r, 0) and np.allclose(g_t, 0)


def test_rotational_gradient_matches_closed_form():
    # Radiance L(w) = w_x: E(n) = 2 pi / 3 n_x, so tilting the normal toward +x by
    # a small angle alpha (n_k x n = alpha * y) raises E by 2 pi / 3 alpha: grad_r = (0, 2 pi/3, 0).
    H = Hemisphere(16, 32)
    cells, w = _random_rays(H, np.random.default_rng(3), per_cell=16)
    L = _cell_means(H, cells, np.repeat(w[:, :1], 3, axis=1))
    axis = _cell_means(H, cells, np.column_stack([-w[:, 1] / w[:, 2], w[:, 0] / w[:, 2], 0 * w[:, 0]]))
    _, g_r, _ = H.irradiance_and_gradients(L[None], np.ones((1, H.cells)), axis[None])
    assert g_r[0, 0, 1] == pytest.approx(2 * np.pi / 3, rel=0.03)
    assert abs(g_r[0, 0, 0]) < 0.03


@pytest.mark.parametrize("axis", [0, 1])
def test_translational_gradient_matches_ceiling_ramp(axis):
    # A ceiling at height h whose radiance grows linearly, L = L0 + g x: E(x) = pi (L0 + g x), grad_t = pi g.
    H = Hemisphere(24, 48)
    h, L0, g = 1.3, 1.0, 0.3
    cells = np.arange(H.cells)
    w = H.sample_cells(cells, np.full((H.cells, 2), 0.5))
    t = h / w[:, 2]
    L = np.repeat((L0 + g * t * w[:, axis])[:, None], 3, axis=1)
    E, _, g_t = H.irradiance_and_gradients(L[None], t[None])
    assert E[0, 0] == pytest.approx(np.pi * L0, rel=1e-6)
    assert g_t[0, 0, axis] == pytest.approx(np.pi * g, rel=0.03)
    assert abs(g_t[0, 0, 1 - axis]) < 1e-9


def test_ordered_sums_equal_the_matrix_products_to_rounding():
    # The sums run term by term (the compiled kernel's order); as matrix products (BLAS's order) they differ
    # in the last bits only.
    rng = np.random.default_rng(4)
    H, B = Hemisphere(6, 10), 5
    L = rng.random((B, H.cells, 3))
    r = rng.uniform(0.01, 2.0, (B, H.cells))
    axis = rng.normal(size=(B, H.cells, 3))
    E, g_r, g_t = H.irradiance_and_gradients(L, r, axis)
    theta_step, phi_step, u, v_lo = H.gradient_coefficients()
    L4, r3 = L.reshape(B, 6, 10, 3), r.reshape(B, 6, 10)
    want_r = H.cell_weight * (L.transpose(0, 2, 1) @ axis)
    theta = (theta_step[None, :, None] / np.minimum(r3[:, 1:], r3[:, :-1]))[..., None] * (L4[:, 1:] - L4[:, :-1])
    phi = (phi_step[None, :, None] / np.minimum(r3, np.roll(r3, 1, axis=2)))[..., None] * (L4 - np.roll(L4, 1, axis=2))
    want_t = theta.sum(axis=1).transpose(0, 2, 1) @ u + phi.sum(axis=1).transpose(0, 2, 1) @ v_lo
    np.testing.assert_allclose(E, H.cell_weight * L.sum(axis=1), rtol=0, atol=0)
    np.testing.assert_allclose(g_r, want_r, rtol=1e-12, atol=1e-12 * np.abs(want_r).max())
    np.testing.assert_allclose(g_t, want_t, rtol=1e-12, atol=1e-12 * np.abs(want_t).max())
