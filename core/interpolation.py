"""Irradiance at arbitrary surface points from the cache: Equations 1 to 3 over many points.

Records are binned by zone radius (a R_k, powers of two) so each kd-tree
query uses a distance bound close to the zones it may hit, and asks only for
the ``k`` nearest records within it: fixed-size, vectorised queries instead of
ragged ball queries. A pure function of its chunk of points.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .irradiance_cache import IrradianceCache, beyond_wall
from .ward import accepted, record_estimate, ward_weight

NEAREST_PER_BIN = 16
"""Records considered per radius bin and point; more than Equation 2 ever accepts in practice."""


@dataclass
class CacheLookup:
    """Query structure over a fixed cache: one kd-tree per power-of-two bin of zone radius."""

    cache: IrradianceCache
    a: float
    use_gradients: bool = True

    def __post_init__(self):
        zone = self.a * self.cache.R
        self.bins = []
        if len(zone) == 0:
            return
        level = np.floor(np.log2(np.maximum(zone, 1e-300))).astype(int)
        for lv in np.unique(level):
            idx = np.flatnonzero(level == lv)
            self.bins.append((idx, cKDTree(self.cache.p[idx]), float(zone[idx].max())))

    def irradiance(self, p: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Equation 3 at points p (m, 3) with unit normals n (m, 3).

        Returns (E (m, 3) float64 >= 0, w_sum (m,) float64); w_sum == 0 marks a hole
        (no record accepted), where E is 0.
        """
        m = len(p)
        num = np.zeros((m, 3))
        den = np.zeros(m)
        c = self.cache
        for idx, tree, radius in self.bins:
            k = min(NEAREST_PER_BIN, len(idx))
            dist, local = tree.query(p, k=k, distance_upper_bound=radius)
            dist, local = dist.reshape(m, k), local.reshape(m, k)
            valid = np.isfinite(dist)
            rows, cols = np.nonzero(valid)
            if len(rows) == 0:
                continue
            rec = idx[local[rows, cols]]
            w = ward_weight(p[rows], n[rows], c.p[rec], c.n[rec], c.R[rec])
            ok = accepted(w, self.a, p[rows], n[rows], c.p[rec], c.n[rec], c.R[rec])
            ok &= ~beyond_wall(c.wall[rec], p[rows] - c.p[rec], c.n[rec])
            rows, rec, w = rows[ok], rec[ok], w[ok]
            E_rec = record_estimate(c.E[rec], p[rows], n[rows], c.p[rec], c.n[rec],
                                    c.grad_r[rec] if self.use_gradients else None,
                                    c.grad_t[rec] if self.use_gradients else None)
            E_rec = np.maximum(E_rec, 0.0)
            for ch in range(3):
                num[:, ch] += np.bincount(rows, weights=w * E_rec[:, ch], minlength=m)
            den += np.bincount(rows, weights=w, minlength=m)
        E = np.divide(num, den[:, None], out=np.zeros_like(num), where=den[:, None] > 0)
        return E, den
