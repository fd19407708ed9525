"""core.vectors and the hot paths' np.take gathers: the same bits as numpy's generic forms they replace."""
import numpy as np
import pytest

from pdic.core.albedo import sample_texture
from pdic.core.scene import Texture
from pdic.core.vectors import norms, unit


def _vectors(shape, dtype=np.float64):
    rng = np.random.default_rng(7)
    # Magnitudes over 20 decades, so a different order of the squares' sum would show in the bits.
    v = rng.normal(size=shape) * 10.0 ** rng.uniform(-10, 10, shape[:-1] + (1,))
    v[..., 0, :] = 0.0  # zero vectors
    return v.astype(dtype)


@pytest.mark.parametrize("shape", [(1000, 3), (200, 7, 3), (50, 4, 6, 3)])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_norms_equal_numpy_norm_bit_for_bit(shape, dtype):
    v = _vectors(shape, dtype)
    expected = np.linalg.norm(v, axis=-1)
    assert norms(v).dtype == expected.dtype
    assert np.array_equal(norms(v), expected)
    assert np.array_equal(norms(v, keepdims=True), np.linalg.norm(v, axis=-1, keepdims=True))
    strided = v[::3]  # not contiguous
    assert np.array_equal(norms(strided), np.linalg.norm(strided, axis=-1))


def test_unit_vectors_and_zero_vectors():
    v = _vectors((500, 3))
    length = np.linalg.norm(v, axis=-1, keepdims=True)
    expected = np.divide(v, length, out=np.zeros_like(v), where=length > 0)
    u = unit(v)
    assert np.array_equal(u, expected)
    assert (u[0] == 0).all() and np.allclose(np.linalg.norm(u[1:], axis=1), 1.0)


def test_bilinear_texture_equals_the_per_pixel_formula():
    """sample_texture gathers rows of the flattened image; the result is the textbook bilinear blend
    of the four pixel centres around each point, with repeat wrapping across the image's edges."""
    rng = np.random.default_rng(3)
    px = rng.random((5, 7, 3)).astype(np.float32)
    uv = rng.uniform(-2.0, 3.0, (400, 2))
    got = sample_texture(Texture("t", px), uv)
    H, W = px.shape[:2]
    x, y = uv[:, 0] * W - 0.5, uv[:, 1] * H - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None].astype(np.float32), (y - y0)[:, None].astype(np.float32)
    i0, j0 = x0.astype(int) % W, y0.astype(int) % H
    i1, j1 = (i0 + 1) % W, (j0 + 1) % H
    expected = ((px[j0, i0] * (1 - fx) + px[j0, i1] * fx) * (1 - fy)
                + (px[j1, i0] * (1 - fx) + px[j1, i1] * fx) * fy)
    assert np.array_equal(got, expected)
