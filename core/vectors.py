"""Lengths and directions of arrays of 3-vectors, for the hot paths.

``np.linalg.norm(v, axis=-1)`` squares through ``conj()`` and a generic reduction: about 3.5x
the cost of the explicit sum below (19 against 5.5 ms for a million vectors), which adds the
same squares in the same order and so returns the same bits (tests/test_vectors.py).
Row gathers in the hot paths use ``np.take(a, index, axis=0)`` for the same reason: 2.5-3.5x
cheaper than ``a[index]`` on (n, 3) arrays, numpy 1.26 and 2.3 alike, and equal.
"""
from __future__ import annotations

import numpy as np


def norms(v: np.ndarray, keepdims: bool = False) -> np.ndarray:
    """Euclidean length of each 3-vector along the last axis of ``v`` (..., 3), in v's float type."""
    squares = v * v  # one multiply, then the sums (as dots: 5.4 against 6.9 ms for a million vectors)
    length = np.sqrt(squares[..., 0] + squares[..., 1] + squares[..., 2])
    return length[..., None] if keepdims else length


def dots(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a . b of 3-vectors along the last axis (..., 3), broadcast, summed left to right.

    ``np.einsum("ij,ij->i", a, b)`` adds the three products in an order its SIMD loops choose
    (numpy 1.26 on x86-64: (a0 b0 + a2 b2) + a1 b1); this order is fixed, so compiled code
    (core/native/pdic_native.c) can match it to the bit on every platform and numpy version. The products
    in one multiply, then the sums: half the time of three strided products (0.5 against 1.0 ms for 100k
    vectors; einsum 0.36), the same bits."""
    products = a * b
    return products[..., 0] + products[..., 1] + products[..., 2]


def unit(v: np.ndarray) -> np.ndarray:
    """``v`` (..., 3) scaled to unit length; zero vectors stay zero."""
    length = norms(v, keepdims=True)
    return np.divide(v, length, out=np.zeros_like(v), where=length > 0)
