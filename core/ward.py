"""Ward's irradiance-cache weights and interpolation (paper Equations 1 to 3, [WRC88], [WH92]).

Conventions, fixed once here:

* Equation 1, ``w_k(p) = 1 / (|p - p_k| / R_k + sqrt(1 - n . n_k))``, has its
  denominator floored at :data:`DENOMINATOR_FLOOR`, so a point on a record
  (p = p_k, n = n_k) gets the large finite weight 1/floor instead of a division
  by zero.
* Equation 2: record k contributes to p only if ``w_k(p) > 1/a``. For coplanar
  points that is exactly the zone of influence ``|p - p_k| < a R_k``.
* Ward's "in front" test drops records lying in front of p (the surface
  around p would occlude them): ``(p - p_k) . (n + n_k)/2 < -IN_FRONT * R_k``.
* Equation 3 with gradients ([WH92], [KGBP05]):
  ``E(p) = sum w_k (E_k + (n_k x n) . grad_r_k + (p - p_k) . grad_t_k) / sum w_k``.
  Extrapolated values are clamped at zero (irradiance is never negative).
"""
from __future__ import annotations

import numpy as np

from .vectors import dots, norms

DENOMINATOR_FLOOR = 1e-6
IN_FRONT = 0.05


def ward_weight(p: np.ndarray, n: np.ndarray, p_k: np.ndarray, n_k: np.ndarray, R_k: np.ndarray) -> np.ndarray:
    """Equation 1 for matching rows: (m,) float64 weights, finite and positive.

    p, n : (m, 3) query points and unit normals; p_k, n_k : (m, 3) records, or (3,) for
    one record against many points; R_k : (m,) or a scalar, > 0.
    """
    return weight_from(norms(p - p_k), dots(n, n_k), R_k)


def weight_from(d: np.ndarray, cos: np.ndarray, R_k: np.ndarray) -> np.ndarray:
    """Equation 1 from its terms: distances d = |p - p_k| and cosines n . n_k, (m,) each."""
    denominator = d / R_k + np.sqrt(1.0 - np.clip(cos, -1.0, 1.0))
    return 1.0 / np.maximum(denominator, DENOMINATOR_FLOOR)


def accepted(w: np.ndarray, a: float, p: np.ndarray, n: np.ndarray, p_k: np.ndarray, n_k: np.ndarray,
             R_k: np.ndarray) -> np.ndarray:
    """Equation 2 plus Ward's in-front test: (m,) bool, may record k contribute at p?"""
    return accepted_from(w, a, dots(p - p_k, n + n_k), R_k)


def accepted_from(w: np.ndarray, a: float, lead: np.ndarray, R_k: np.ndarray) -> np.ndarray:
    """:func:`accepted` from its terms: lead = (p - p_k) . (n + n_k), (m,)."""
    return (w > 1.0 / a) & ~(0.5 * lead < -IN_FRONT * R_k)


def record_estimate(E_k: np.ndarray, p: np.ndarray, n: np.ndarray, p_k: np.ndarray, n_k: np.ndarray,
                    grad_r: np.ndarray | None, grad_t: np.ndarray | None) -> np.ndarray:
    """Record k's extrapolated irradiance at p: E_k + (n_k x n) . grad_r + (p - p_k) . grad_t.

    E_k : (m, 3) RGB; grad_r, grad_t : (m, 3, 3) [row, channel, xyz] or None.
    """
    E = E_k.astype(np.float64, copy=True)
    if grad_r is not None:
        E += dots(grad_r, np.cross(n_k, n)[:, None, :])
    if grad_t is not None:
        E += dots(grad_t, (p - p_k)[:, None, :])
    return E
