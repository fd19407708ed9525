"""The hemisphere cells of one batch of records being refined (pass 3, section 3.3).

:class:`CellSums` accumulates what real and virtual rays bring to each cell (radiance, the
rotational-gradient axis, the nearest hit) and to each record (1/distance for R_k), and turns
the cells into E_k and its gradients ([WH92], :mod:`core.hemisphere`).
"""
from __future__ import annotations

import numpy as np

from . import native_kernels
from .constants import GRADIENT_LIMIT
from .hemisphere import Hemisphere, gradient_to_world
from .vectors import norms


class CellSums:
    """Running sums over B records x C cells (flat index record * C + cell).

    L_sum, rot_sum : (B C, 3) weighted radiance and rotational-gradient axis (z x w) / cos; with the
        sky gathered (deviation: sky-gathering) L_sum has 6 channels, the world's radiance in 3-5.
    count : (B C,) summed ray weights (rays per cell for real rays).
    r_min : (B C,) nearest hit distance per cell.
    inv_d_sum, inv_d_count : (B,) sums of 1 / distance and their counts (R_k's harmonic mean).
    """

    def __init__(self, records: int, hemisphere: Hemisphere, sky: bool = False):
        self.B, self.H = records, hemisphere
        size = records * hemisphere.cells
        self.L_sum = np.zeros((size, 6 if sky else 3))
        self.rot_sum = np.zeros((size, 3))
        self.count = np.zeros(size)
        self.r_min = np.full(size, np.inf)
        self.inv_d_sum = np.zeros(records)
        self.inv_d_count = np.zeros(records)
        self.glass_rays = 0
        """Rays cast on past glass (:func:`core.real_rays.through_glass`)."""

    @property
    def size(self) -> int:
        return len(self.count)

    def add_rays(self, cell: np.ndarray, L: np.ndarray, w_local: np.ndarray, dist: np.ndarray,
                 inv_weight: np.ndarray | None = None):
        """Add rays to their cells: radiance, rotational-gradient axis (z x w)/cos, count, min distance.

        With ``inv_weight`` (phi / L per ray) the cell's radiance becomes sum(phi) / sum(phi / L):
        ray i enters with weight w_i = (phi_i / L_i) / mean over the cell, so sum(w_i L_i) / sum(w_i)
        is exactly that harmonic mean (deviation: harmonic-cell-radiance).
        """
        size = self.size
        if inv_weight is None:
            w = np.ones(len(cell))
        else:
            total = np.bincount(cell, weights=inv_weight, minlength=size)
            n = np.bincount(cell, minlength=size)
            w = inv_weight / np.maximum(total[cell] / np.maximum(n[cell], 1), 1e-300)
        for c in range(3):
            self.L_sum[:, c] += np.bincount(cell, weights=w * L[:, c], minlength=size)
        cos = np.maximum(w_local[:, 2], 1e-6)
        self.rot_sum[:, 0] += np.bincount(cell, weights=w * -w_local[:, 1] / cos, minlength=size)
        self.rot_sum[:, 1] += np.bincount(cell, weights=w * w_local[:, 0] / cos, minlength=size)
        self.count += np.bincount(cell, weights=w, minlength=size)
        np.minimum.at(self.r_min, cell, dist)

    def add_real_rays(self, cell: np.ndarray, w_local: np.ndarray, dist: np.ndarray):
        """Add one real ray to each of the given distinct, still empty cells: its rotational-gradient
        axis, count 1 and hit distance (inf on a miss). Its radiance follows with :meth:`add_real_radiance`.

        The same sums :meth:`add_rays` makes with unit weights, written in place: the cells are distinct,
        so no bincount over all B C cells is needed.
        """
        cos = np.maximum(w_local[:, 2], 1e-6)
        self.rot_sum[cell, 0] += -w_local[:, 1] / cos
        self.rot_sum[cell, 1] += w_local[:, 0] / cos
        self.count[cell] += 1.0
        self.r_min[cell] = np.minimum(self.r_min[cell], dist)

    def add_real_radiance(self, cell: np.ndarray, L: np.ndarray):
        """Add (h, 3) radiance to the distinct cells of real rays already counted by :meth:`add_real_rays`."""
        lib = native_kernels.library()
        if lib is None:
            self.L_sum[cell, :3] += L
        else:
            native_kernels.add_rows3(lib, self.L_sum, cell, L)

    def add_sky(self, cell: np.ndarray, L_world: np.ndarray):
        """The world's radiance L_world, (3,) or one per cell (h, 3), into the sky channels of the distinct
        cells whose real ray reached it (deviation: sky-gathering)."""
        self.L_sum[cell, 3:] += L_world

    def add_distances(self, inv_sum: np.ndarray, inv_n: np.ndarray):
        """Per-record sums (B,) of 1 / hit distance and hit counts."""
        self.inv_d_sum += inv_sum
        self.inv_d_count += inv_n

    def empty_cells(self) -> np.ndarray:
        """Flat indices of the cells no ray reached yet."""
        return np.flatnonzero(self.count == 0)

    def standard_error(self) -> np.ndarray:
        """(B,) standard error of E_k's channel mean, from the cells' pairs of phi neighbours.

        Each pair is taken as two samples of one stratum of twice the size, so the estimate also
        counts how the radiance varies between the two cells: it errs on the high side.
        """
        B, M, N = self.B, self.H.rows, self.H.columns
        L = (self.L_sum / np.maximum(self.count, 1)[:, None]).mean(axis=1).reshape(B, M, N)
        d = L[:, :, 0:N - 1:2] - L[:, :, 1::2]
        return self.H.cell_weight * np.sqrt(np.einsum("bjk,bjk->b", d, d))

    def irradiance_and_gradients(self, t1, t2, n, r_floor: float) -> tuple:
        """(E (B, c) >= 0, grad_r, grad_t (B, c, 3) world, R (B,) harmonic mean hit distance); c = 6 with
        the sky's channels."""
        lib = native_kernels.library()
        E, g_r, g_t = self.local_gradients(r_floor) if lib is None else native_kernels.cell_gradients(lib, self, r_floor)
        R = np.divide(self.inv_d_count, self.inv_d_sum, out=np.full(self.B, np.inf), where=self.inv_d_sum > 0)
        return np.maximum(E, 0.0), gradient_to_world(g_r, t1, t2, n), gradient_to_world(g_t, t1, t2, n), R

    def local_gradients(self, r_floor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(E (B, c), grad_r, grad_t (B, c, 3) in the records' local frames) from the cells' means, no cell
        nearer than r_floor (compiled: :func:`core.native_kernels.cell_gradients`)."""
        B, C = self.B, self.H.cells
        L_cell = (self.L_sum / np.maximum(self.count, 1)[:, None]).reshape(B, C, -1)
        rot_cell = (self.rot_sum / np.maximum(self.count, 1)[:, None]).reshape(B, C, 3)
        # A hit at (nearly) zero distance would make the translational gradient overflow: no cell
        # is nearer than r_floor (gradient limiting then caps what is left).
        r_cell = np.maximum(self.r_min.reshape(B, C), r_floor)
        return self.H.irradiance_and_gradients(L_cell, r_cell, rot_cell)


def limit_gradients(E: np.ndarray, grad_t: np.ndarray, grad_r: np.ndarray, zone_radius: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Gradient limiting: extrapolation across a zone may change E_k by at most GRADIENT_LIMIT x E_k.

    deviation: gradient-limiting, docs/DEVIATIONS.md. Ward & Heckbert's translational gradient
    divides by the distance of each cell's hit; near a corner that distance is tiny and a single
    cell makes the gradient explode. Each channel's |grad_t| is capped at GRADIENT_LIMIT x E_k / (a R_k)
    and |grad_r| at E_k (per radian), as production irradiance caches do.
    """
    def cap(grad, limit):
        norm = norms(grad)  # (K, 3 channels)
        scale = np.divide(limit, norm, out=np.ones_like(norm), where=norm > limit)
        return grad * scale[..., None]

    return (cap(grad_t, GRADIENT_LIMIT * E / np.maximum(zone_radius, 1e-300)[:, None]),
            cap(grad_r, E))
