"""The stratified hemisphere above a record, and irradiance and its gradients from its cells.

Cells are laid out for cosine weighting (paper section 3.3, [WH92]): M rows in
theta with sin^2(theta) uniform in [j/M, (j+1)/M] and N columns in phi, so
every cell carries the same cosine-weighted solid angle pi / (M N) and

    E = pi / (M N) * sum_{j,k} L_{j,k}.

Gradients follow Ward & Heckbert 1992 in the form of Krivanek et al. 2005
("Improved radiance gradient computation"), with cell radiances L_{j,k} and
the distance r_{j,k} to what each cell's ray hit:

    grad_r E = pi/(M N) * sum_k v_k * sum_j tan(theta_j) L_{j,k}   (= integral of L (n x w) dw)

    grad_t E = sum_k [ u_k * 2 pi / N * sum_{j>=1} sin(theta_j^-) cos^2(theta_j^-)
                                       / min(r_{j,k}, r_{j-1,k}) * (L_{j,k} - L_{j-1,k})
                     + v_k^- * sum_j (sin theta_j^+ - sin theta_j^-)
                                       / min(r_{j,k}, r_{j,k-1}) * (L_{j,k} - L_{j,k-1}) ]

where theta_j is the row centre, theta_j^-/+ its lower/upper boundary, u_k the
unit vector at the column's centre angle phi_k, v_k = u_k rotated by +90
degrees, and v_k^- the unit vector perpendicular to the boundary phi between
columns k-1 and k. The phi-boundary coefficient is the projected solid angle
a boundary sweeps per unit translation, integral of cos(t) sin(t) / (r sin(t)) dt
over the row; Ward & Heckbert's (cos theta^- - cos theta^+) / sin theta drops
the cos(t) and overestimates it (tests/test_hemisphere.py checks both terms
against a closed form: a ceiling with a linear radiance ramp, grad_t = pi g).
Gradients are expressed in the record's tangent frame and returned in
scene-local xyz.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .sampling import orthonormal_basis


@dataclass(frozen=True)
class Hemisphere:
    """Stratification with M theta rows and N phi columns (cells = M N)."""

    rows: int
    columns: int

    @property
    def cells(self) -> int:
        return self.rows * self.columns

    @property
    def cell_weight(self) -> float:
        """Cosine-weighted solid angle of one cell: pi / (M N)."""
        return np.pi / self.cells

    def cell_of(self, w_local: np.ndarray) -> np.ndarray:
        """(n,) int64 cell index j*N + k of local unit directions (n, 3) with z > 0."""
        sin2 = np.clip(1.0 - w_local[:, 2] ** 2, 0.0, np.nextafter(1.0, 0.0))
        j = np.minimum((sin2 * self.rows).astype(np.int64), self.rows - 1)
        phi = np.mod(np.arctan2(w_local[:, 1], w_local[:, 0]), 2 * np.pi)
        k = np.minimum((phi / (2 * np.pi) * self.columns).astype(np.int64), self.columns - 1)
        return j * self.columns + k

    def sample_cells(self, cells: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Local unit directions (n, 3), uniform in cosine-weighted measure inside each given cell."""
        j, k = np.divmod(cells, self.columns)
        sin2 = (j + u[:, 0]) / self.rows
        phi = 2 * np.pi * (k + u[:, 1]) / self.columns
        s = np.sqrt(sin2)
        return np.column_stack([s * np.cos(phi), s * np.sin(phi), np.sqrt(np.maximum(0.0, 1.0 - sin2))])

    def _angles(self):
        j = np.arange(self.rows)
        theta_lo = np.arcsin(np.sqrt(j / self.rows))
        theta_hi = np.arcsin(np.sqrt((j + 1) / self.rows))
        theta_mid = np.arcsin(np.sqrt((j + 0.5) / self.rows))
        k = np.arange(self.columns)
        phi_mid = 2 * np.pi * (k + 0.5) / self.columns
        phi_lo = 2 * np.pi * k / self.columns
        return theta_lo, theta_hi, theta_mid, phi_mid, phi_lo

    def irradiance_and_gradients(self, L: np.ndarray, r: np.ndarray, rot_axis: np.ndarray | None = None
                                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """E, rotational and translational gradients in the *local* frame from cell radiances.

        L : (B, M*N, c) cell radiances (c channels: RGB, or RGB twice with the sky's); r : (B, M*N) hit
            distances (> 0; inf for misses).
        rot_axis : (B, M*N, 3) optional per-cell mean of (z x w) / cos(theta) over the
            cell's actual ray directions w; the cell centre's value when omitted.
            Near the horizon tan(theta) varies fast across a row, so the rays' own
            directions estimate the rotational gradient better than the centres.
        Returns E (B, c), grad_r (B, c channels, 3 local xyz), grad_t (B, c, 3); z components are 0.
        Every sum runs over cells (or rows, or columns) in order, one term after another, as
        ``pdic_cell_gradients`` (core/native) sums them: no matrix product, whose order is the BLAS's.
        """
        B, c = L.shape[0], L.shape[-1]
        M, N = self.rows, self.columns
        L = L.reshape(B, M, N, c)
        r = np.maximum(r.reshape(B, M, N), 1e-300)
        E = self.cell_weight * L.reshape(B, M * N, c).sum(axis=1)
        if rot_axis is None:
            theta_mid = self._angles()[2]
            rot_axis = np.tan(theta_mid)[:, None, None] * self.v_mid()[None]  # (M, N, 3)
            rot_axis = np.broadcast_to(rot_axis.reshape(1, M * N, 3), (B, M * N, 3))
        # Rotational: the cell sum of L (n x w) dw (Ward & Heckbert write -tan with v pointing the other way).
        grad_r = self.cell_weight * _ordered_products(L.reshape(B, M * N, c), rot_axis.reshape(B, M * N, 3))
        theta_step, phi_step, u, v_lo = self.gradient_coefficients()
        grad_t = np.zeros((B, c, 3))
        if M > 1:  # translational, theta boundaries (rows j-1 | j), j >= 1
            weight = theta_step[None, :, None] / np.minimum(r[:, 1:], r[:, :-1])  # (B, M-1, N)
            term = (weight[..., None] * (L[:, 1:] - L[:, :-1])).sum(axis=1)  # (B, N, c)
            grad_t += _ordered_products(term, np.broadcast_to(u, (B, N, 3)))
        if N > 1:  # translational, phi boundaries (columns k-1 | k), wrapping around
            weight = phi_step[None, :, None] / np.minimum(r, np.roll(r, 1, axis=2))
            term = (weight[..., None] * (L - np.roll(L, 1, axis=2))).sum(axis=1)
            grad_t += _ordered_products(term, np.broadcast_to(v_lo, (B, N, 3)))
        return E, grad_r, grad_t

    def v_mid(self) -> np.ndarray:
        """(N, 3) the unit vectors v_k at the columns' centre angles, u_k turned by +90 degrees."""
        phi_mid = self._angles()[3]
        return np.stack([-np.sin(phi_mid), np.cos(phi_mid), np.zeros(self.columns)], axis=1)

    def gradient_coefficients(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What the translational gradient weighs boundaries by: (theta_step (M-1,) 2 pi / N sin cos^2 at
        each row's lower boundary but the first, phi_step (M,) sin theta^+ - sin theta^- per row, u (N, 3)
        at the columns' centres, v_lo (N, 3) perpendicular to the columns' lower boundaries)."""
        M, N = self.rows, self.columns
        theta_lo, theta_hi, _, phi_mid, phi_lo = self._angles()
        theta_step = (2 * np.pi / N) * (np.sin(theta_lo[1:]) * np.cos(theta_lo[1:]) ** 2)
        phi_step = np.sin(theta_hi) - np.sin(theta_lo)
        u = np.stack([np.cos(phi_mid), np.sin(phi_mid), np.zeros(N)], axis=1)
        v_lo = np.stack([-np.sin(phi_lo), np.cos(phi_lo), np.zeros(N)], axis=1)
        return theta_step, phi_step, u, v_lo


def _ordered_products(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(B, c, 3) sum over i of a[:, i, :, None] b[:, i, None, :] for a (B, I, c), b (B, I, 3), i in order.

    numpy sums over a leading axis term by term from +0.0 while the trailing axes hold more than one value
    (c >= 2 here; over a trailing axis of one it sums pairwise), which is what lets C match it to the bit."""
    return (a[:, :, :, None] * b[:, :, None, :]).sum(axis=1)


def local_frames(n: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t1, t2, n) orthonormal frames (B, 3) each for record normals (B, 3)."""
    t1, t2 = orthonormal_basis(n)
    return t1, t2, n


def to_local(v: np.ndarray, t1: np.ndarray, t2: np.ndarray, n: np.ndarray) -> np.ndarray:
    return np.stack([np.einsum("ij,ij->i", v, t1), np.einsum("ij,ij->i", v, t2), np.einsum("ij,ij->i", v, n)], axis=1)


def gradient_to_world(grad_local: np.ndarray, t1: np.ndarray, t2: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Rotate (B, 3, 3) [record, channel, local xyz] gradients into scene-local xyz."""
    return (grad_local[..., 0:1] * t1[:, None, :] + grad_local[..., 1:2] * t2[:, None, :]
            + grad_local[..., 2:3] * n[:, None, :])
