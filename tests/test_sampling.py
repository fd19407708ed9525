"""Every sampler against its pdf: densities integrate to one, estimators reproduce known integrals."""
import numpy as np
import pytest
from scipy import stats

from pdic.core import sampling

N = 200_000


def test_orthonormal_basis_is_orthonormal_and_right_handed(rng):
    n = rng.normal(size=(1000, 3))
    n = np.concatenate([n, np.eye(3), -np.eye(3), [[0.0, 0.0, -1.0 + 1e-12]]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    t1, t2 = sampling.orthonormal_basis(n)
    for a, b in ((t1, t2), (t1, n), (t2, n)):
        assert np.abs(np.sum(a * b, axis=1)).max() < 1e-12
    for a in (t1, t2):
        assert np.allclose(np.linalg.norm(a, axis=1), 1.0, atol=1e-12)
    assert np.allclose(np.cross(t1, t2), n, atol=1e-12)


def test_cosine_hemisphere_pdf_passes_chi_square(rng):
    w, pdf = sampling.cosine_hemisphere(rng.random((N, 2)))
    assert np.allclose(np.linalg.norm(w, axis=1), 1.0) and w[:, 2].min() >= 0.0
    assert np.allclose(pdf, w[:, 2] / np.pi)
    # Under cos/pi, cos^2(theta) and phi / 2pi are independent and uniform: 10 x 10 equal cells.
    a = w[:, 2] ** 2
    b = (np.arctan2(w[:, 1], w[:, 0]) + np.pi) / (2 * np.pi)
    counts, _, _ = np.histogram2d(a, b, bins=10, range=[[0, 1], [0, 1]])
    chi2, p_value = stats.chisquare(counts.ravel())
    assert p_value > 1e-3, chi2


def test_cosine_hemisphere_reproduces_hemisphere_integrals(rng):
    w, pdf = sampling.cosine_hemisphere(rng.random((N, 2)))
    # integral of 1 over the hemisphere = 2 pi; of cos^2 = 2 pi / 3; E[cos] = 2/3.
    assert np.mean(1.0 / pdf) == pytest.approx(2 * np.pi, rel=0.02)
    assert np.mean(w[:, 2] ** 2 / pdf) == pytest.approx(2 * np.pi / 3, rel=2e-3)
    assert np.mean(w[:, 2]) == pytest.approx(2 / 3, rel=2e-3)


def test_cosine_hemisphere_pdf_integrates_to_one():
    # Midpoint quadrature over (theta, phi): integral of pdf sin(theta) = 1.
    theta = (np.arange(2000) + 0.5) / 2000 * (np.pi / 2)
    integral = np.sum(sampling.cosine_hemisphere_pdf(np.cos(theta)) * np.sin(theta)) * (np.pi / 2 / 2000) * 2 * np.pi
    assert integral == pytest.approx(1.0, rel=1e-6)


def test_to_world_maps_local_z_onto_normal(rng):
    n = rng.normal(size=(50, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    assert np.allclose(sampling.to_world(np.tile([0.0, 0.0, 1.0], (50, 1)), n), n)


@pytest.mark.parametrize("shape", ["per_point", "pattern", "one_normal"])
def test_to_world_is_the_tangent_frames_sum_to_the_bit(rng, shape):
    """w_x t1 + w_y t2 + w_z n with orthonormal_basis's tangents, summed in that order, for one frame per
    direction, a pattern of directions per point, and one frame for all; normals (0, 0, +-1) included."""
    w = sampling.cosine_hemisphere(rng.random((500, 2)))[0]
    n = rng.normal(size=(500, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n[:2] = [[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]
    w, n = {"per_point": (w, n), "pattern": (w[:9][None], n[:, None]), "one_normal": (w, n[7])}[shape]
    t1, t2 = sampling.orthonormal_basis(n)
    assert np.array_equal(sampling.to_world(w, n), w[..., 0:1] * t1 + w[..., 1:2] * t2 + w[..., 2:3] * n)


def test_cosine_hemisphere_lifts_the_concentric_disk_to_the_bit(rng):
    u = rng.random((1000, 2))
    u[:3] = [[0.5, 0.5], [0.0, 0.0], [0.5, 0.25]]  # the disk's centre (phi 0) and its axes
    d = sampling.concentric_disk(u)[0]
    w, pdf = sampling.cosine_hemisphere(u)
    assert np.array_equal(w[:, :2], d)
    assert np.array_equal(w[:, 2], np.sqrt(np.maximum(0.0, 1.0 - np.sum(d * d, axis=-1))))
    assert np.array_equal(pdf, np.maximum(w[:, 2], 0.0) / np.pi)


@pytest.mark.parametrize("m,grid", [(16, (4, 4)), (8, (2, 4)), (12, (3, 4)), (7, (1, 7)), (1, (1, 1))])
def test_stratified_samples_put_one_sample_in_each_cell(rng, m, grid):
    assert sampling.strata(m) == grid
    u = sampling.stratified_2d(300, m, rng)
    assert u.shape == (300, m, 2) and u.min() >= 0.0 and u.max() < 1.0
    cell = np.floor(u[..., 0] * grid[0]).astype(int) * grid[1] + np.floor(u[..., 1] * grid[1]).astype(int)
    assert all(sorted(row) == list(range(m)) for row in cell)


def test_stratified_samples_are_uniform_over_the_square(rng):
    u = sampling.stratified_2d(5000, 16, rng).reshape(-1, 2)
    counts, _, _ = np.histogram2d(u[:, 0], u[:, 1], bins=8, range=[[0, 1], [0, 1]])
    assert stats.chisquare(counts.ravel()).pvalue > 1e-3


def test_concentric_disk_is_uniform_with_pdf_one_over_pi(rng):
    p, pdf = sampling.concentric_disk(rng.random((N, 2)))
    r2 = np.sum(p * p, axis=1)
    assert r2.max() <= 1.0 + 1e-12
    assert np.mean(1.0 / pdf) == pytest.approx(np.pi)
    # r^2 uniform on [0, 1] and the angle uniform for a uniform disk.
    assert stats.kstest(r2, "uniform").pvalue > 1e-3
    assert stats.kstest((np.arctan2(p[:, 1], p[:, 0]) + np.pi) / (2 * np.pi), "uniform").pvalue > 1e-3
    assert np.all(np.isfinite(sampling.concentric_disk(np.array([[0.5, 0.5]]))[0]))


def test_uniform_triangle_moments_match_dirichlet(rng):
    bary, pdf = sampling.uniform_triangle(rng.random((N, 2)))
    b = np.column_stack([1 - bary.sum(1), bary])
    assert b.min() >= 0.0
    # Uniform on a triangle: barycentrics ~ Dirichlet(1,1,1): mean 1/3, E[b^2] = 1/6.
    assert np.allclose(b.mean(0), 1 / 3, atol=3e-3)
    assert np.allclose((b * b).mean(0), 1 / 6, atol=3e-3)
    # pdf 2 on the reference triangle of area 1/2; 1/area on a real one.
    assert np.mean(1.0 / pdf) == pytest.approx(0.5)
    assert sampling.uniform_triangle_pdf(np.array([4.0, 0.0])).tolist() == [0.25, 0.0]


@pytest.mark.parametrize("half_angle", [np.radians(0.2665), np.radians(10.0), np.radians(60.0), np.pi / 2])
def test_uniform_cone_reproduces_projected_solid_angle(rng, half_angle):
    omc = 2 * np.sin(half_angle / 2) ** 2
    w, pdf = sampling.uniform_cone(rng.random((N, 2)), omc)
    assert np.allclose(np.linalg.norm(w, axis=1), 1.0)
    assert w[:, 2].min() >= np.cos(half_angle) - 1e-12
    # integral of 1 = 2 pi (1 - cos a); integral of cos = pi sin^2 a.
    assert np.mean(1.0 / pdf) == pytest.approx(2 * np.pi * omc, rel=1e-9)
    assert np.mean(w[:, 2] / pdf) == pytest.approx(np.pi * np.sin(half_angle) ** 2, rel=2e-3)


@pytest.mark.parametrize("shape", ["rectangle", "ellipse"])
def test_planar_shapes_cover_their_area_uniformly(rng, shape):
    su, sv = 0.8, 0.3
    fn = sampling.uniform_rectangle if shape == "rectangle" else sampling.uniform_ellipse
    p, pdf = fn(rng.random((N, 2)), su, sv)
    area = su * sv if shape == "rectangle" else np.pi * su * sv / 4
    assert np.mean(1.0 / pdf) == pytest.approx(area)
    if shape == "rectangle":
        assert np.abs(p[:, 0]).max() <= su / 2 and np.abs(p[:, 1]).max() <= sv / 2
        inner = (np.abs(p[:, 0]) < su / 4) & (np.abs(p[:, 1]) < sv / 4)
    else:
        assert ((p[:, 0] / (su / 2)) ** 2 + (p[:, 1] / (sv / 2)) ** 2).max() <= 1 + 1e-12
        inner = (p[:, 0] / (su / 4)) ** 2 + (p[:, 1] / (sv / 4)) ** 2 < 1
    assert inner.mean() == pytest.approx(0.25, abs=0.005)  # a quarter of the area holds a quarter of the points


def test_sphere_cone_directions_hit_the_sphere_and_integrate_its_projected_solid_angle(rng):
    centre, radius = np.array([0.2, -0.1, 2.0]), 0.5
    p = np.zeros((1, 3))
    w, t, pdf = sampling.sphere_cone(rng.random((1, N, 2)), p, centre, radius)
    hit = p[:, None, :] + t[..., None] * w
    assert np.allclose(np.linalg.norm(hit - centre, axis=-1), radius, atol=1e-9)
    D = np.linalg.norm(centre)
    # integral over the subtended cone of cos(angle to +z) = pi (r/D)^2 (centre . z / D).
    assert np.mean(w[..., 2] / pdf) == pytest.approx(np.pi * (radius / D) ** 2 * centre[2] / D, rel=3e-3)


def test_disk_facing_lies_on_the_facing_disk_with_pdf_one_over_area(rng):
    centre, radius = np.array([0.0, 0.0, 1.0]), 0.3
    p = rng.normal(size=(20, 3))
    q, n_disk, pdf = sampling.disk_facing(rng.random((20, 500, 2)), p, centre, radius)
    assert np.allclose(n_disk, (p - centre) / np.linalg.norm(p - centre, axis=1, keepdims=True))
    rel = q - centre
    assert np.abs(np.einsum("kmi,ki->km", rel, n_disk)).max() < 1e-12
    assert np.linalg.norm(rel, axis=-1).max() <= radius * (1 + 1e-12)
    assert np.mean(1.0 / pdf) == pytest.approx(np.pi * radius ** 2)
