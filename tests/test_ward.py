"""Ward weights and cache interpolation (Equations 1-3): finite everywhere, exact where it must be."""
import numpy as np

from pdic.core.interpolation import CacheLookup
from pdic.core.irradiance_cache import IrradianceCache
from pdic.core.ward import DENOMINATOR_FLOOR, ward_weight


def _cache(p, n, E, R, grad_t=None):
    K = len(p)
    return IrradianceCache(p=np.asarray(p, float), n=np.asarray(n, float), E=np.asarray(E, float),
                           R=np.asarray(R, float), grad_r=np.zeros((K, 3, 3)),
                           grad_t=np.zeros((K, 3, 3)) if grad_t is None else grad_t,
                           photons_used=np.zeros(K, np.int32), hole=np.zeros(K, bool), refined=np.zeros(K, bool))


def test_equation_1_never_divides_by_zero_at_the_record():
    p = np.zeros((1, 3))
    n = np.array([[0.0, 0.0, 1.0]])
    w = ward_weight(p, n, p, n, np.array([1.0]))
    assert np.isfinite(w).all() and w[0] == 1.0 / DENOMINATOR_FLOOR


def test_interpolation_at_a_record_returns_its_irradiance():
    cache = _cache([[0, 0, 0], [0.5, 0, 0]], [[0, 0, 1]] * 2, [[1, 2, 3], [4, 5, 6]], [1.0, 1.0])
    E, w = CacheLookup(cache, a=0.5).irradiance(np.array([[0.0, 0, 0]]), np.array([[0.0, 0, 1]]))
    assert np.allclose(E, [[1, 2, 3]], rtol=1e-5) and np.isfinite(w).all()


def test_points_outside_every_zone_are_holes_not_nan():
    cache = _cache([[0, 0, 0]], [[0, 0, 1]], [[1, 1, 1]], [1.0])
    E, w = CacheLookup(cache, a=0.3).irradiance(np.array([[5.0, 0, 0], [0.0, 0, 0]]),
                                                np.array([[0, 0, 1.0], [0, 0, -1.0]]))
    assert np.all(w == 0) and np.all(E == 0)


def test_randomised_interpolation_stays_finite_and_within_record_range():
    rng = np.random.default_rng(7)
    for trial in range(20):
        K = int(rng.integers(1, 200))
        p = rng.normal(size=(K, 3)) * 10 ** rng.uniform(-3, 3)
        n = rng.normal(size=(K, 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        E = rng.uniform(0, 1e6, size=(K, 3))
        R = 10 ** rng.uniform(-4, 2, size=K)
        cache = _cache(p, n, E, R)
        q = np.concatenate([p, p + rng.normal(size=p.shape) * R[:, None] * 0.1])
        qn = np.concatenate([n, n])
        E_q, w = CacheLookup(cache, a=0.4, use_gradients=False).irradiance(q, qn)
        assert np.isfinite(E_q).all() and np.isfinite(w).all()
        covered = w > 0
        assert covered[:K].all()  # a record always covers its own position
        assert (E_q[covered] <= E.max() * (1 + 1e-9)).all() and (E_q >= 0).all()


def test_gradients_reconstruct_a_smooth_field_better():
    # E(x, y) = 2 + 0.8 x + 0.5 y + 0.1 sin(2 x) on the plane z = 0; irregularly placed records
    # (as Algorithm 1 places them) carry the exact E and translational gradient.
    rng = np.random.default_rng(5)
    p = np.column_stack([rng.uniform(0, 3, 60), rng.uniform(0, 3, 60), np.zeros(60)])
    field = lambda q: 2 + 0.8 * q[:, 0] + 0.5 * q[:, 1] + 0.1 * np.sin(2 * q[:, 0])  # noqa: E731
    E = np.repeat(field(p)[:, None], 3, axis=1)
    grad = np.zeros((len(p), 3, 3))
    grad[:, :, 0] = (0.8 + 0.2 * np.cos(2 * p[:, 0]))[:, None]
    grad[:, :, 1] = 0.5
    cache = _cache(p, np.tile([0, 0, 1.0], (len(p), 1)), E, np.full(len(p), 1.0), grad)
    q = np.column_stack([rng.uniform(0.3, 2.7, 2000), rng.uniform(0.3, 2.7, 2000), np.zeros(2000)])
    qn = np.tile([0, 0, 1.0], (2000, 1))
    truth = field(q)
    E_with, w = CacheLookup(cache, 0.7, True).irradiance(q, qn)
    E_without, _ = CacheLookup(cache, 0.7, False).irradiance(q, qn)
    covered = w > 0
    assert covered.mean() > 0.9
    err_with = np.abs(E_with[covered, 0] - truth[covered]).mean()
    err_without = np.abs(E_without[covered, 0] - truth[covered]).mean()
    assert err_with < 0.3 * err_without
