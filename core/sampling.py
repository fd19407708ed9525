"""Sampling routines, each with its density beside it (STYLE.md, principle 7).

Every sampler maps uniform numbers ``u`` in [0, 1) to a point or direction
and returns the density of what it produced, in the measure named in its
docstring (solid angle for directions, area for points). Tests check every
pair: the density integrates to one, or the estimator reproduces a known
integral.

All functions are vectorised over leading axes: ``u`` of shape (..., 2)
gives results of shape (..., 3) or (..., 2) and densities of shape (...).
Local frames are z-up: a direction ``w_local`` is turned into a world
direction with the basis of :func:`orthonormal_basis` by :func:`to_world`.
"""
from __future__ import annotations

import numpy as np

from . import native_kernels
from .vectors import norms


# --------------------------------------------------------------------------- frames
def orthonormal_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents completing unit normals ``n`` to a right-handed frame.

    Branchless construction of Duff et al. 2017, "Building an Orthonormal
    Basis, Revisited" (JCGT 6(1)); continuous everywhere except across
    n_z = 0 with n_z's sign, exact for n = (0, 0, -1).

    Parameters
    ----------
    n : (..., 3) float64 unit normals.

    Returns
    -------
    t1, t2 : (..., 3) float64 unit tangents with t1 x t2 = n.
    """
    t1, t2, _ = _tangent_components(n)
    return np.stack(t1, axis=-1), np.stack(t2, axis=-1)


def _tangent_components(n: np.ndarray) -> tuple[tuple, tuple, np.ndarray]:
    """(t1's components, t2's, n as float64): :func:`orthonormal_basis`'s tangents, each component (...,)."""
    n = np.asarray(n, dtype=np.float64)
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    sign = np.where(z >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    return (1.0 + sign * x * x * a, sign * b, -sign * x), (b, sign + y * y * a, -y), n


def to_world(w_local: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Rotate z-up local directions (..., 3) into the frame of unit normals ``n`` (..., 3): w_x t1 + w_y t2 + w_z n
    with :func:`orthonormal_basis`'s tangents, written a component at a time (no (..., 3) tangents: a bake
    turns ~40 M directions, for its texels' validity and its gap walks)."""
    t1, t2, n = _tangent_components(n)
    w_x, w_y, w_z = w_local[..., 0], w_local[..., 1], w_local[..., 2]
    out = np.empty(np.broadcast_shapes(w_x.shape, n.shape[:-1]) + (3,))
    for c in range(3):
        out[..., c] = w_x * t1[c] + w_y * t2[c] + w_z * n[..., c]
    return out


# --------------------------------------------------------------------------- stratification
def strata(m: int) -> tuple[int, int]:
    """Grid (gx, gy) with gx * gy = m and gx the largest divisor of m not above sqrt(m).

    16 -> (4, 4), 8 -> (2, 4), 12 -> (3, 4); a prime m degrades to (1, m), still
    stratified along the second axis.
    """
    if m < 1:
        raise ValueError(f"need at least one sample, got {m}")
    gx = int(np.floor(np.sqrt(m)))
    while m % gx:
        gx -= 1
    return gx, m // gx


def stratified_2d(n: int, m: int, rng: np.random.Generator) -> np.ndarray:
    """Jittered samples: for each of ``n`` points, ``m`` points in [0, 1)^2, one per grid cell.

    Parameters
    ----------
    n : number of receiving points.
    m : samples per point; the unit square is cut into :func:`strata` (gx, gy) cells.
    rng : random stream; each point gets its own independent jitter.

    Returns
    -------
    (n, m, 2) float64 uniform numbers, each marginally uniform on [0, 1)^2
    (density 1 on the square).
    """
    gx, gy = strata(m)
    i, j = np.meshgrid(np.arange(gx), np.arange(gy), indexing="ij")
    corner = np.stack([i.ravel() / gx, j.ravel() / gy], axis=-1)  # (m, 2)
    jitter = rng.random((n, m, 2)) * np.array([1.0 / gx, 1.0 / gy])
    return np.minimum(corner[None] + jitter, np.nextafter(1.0, 0.0))


# --------------------------------------------------------------------------- hemisphere
def cosine_hemisphere(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cosine-weighted directions in the z-up hemisphere (Malley's method on a concentric disk).

    Parameters
    ----------
    u : (..., 2) float64 uniform numbers in [0, 1).

    Returns
    -------
    w_local : (..., 3) float64 unit directions, z >= 0.
    pdf : (...,) float64 solid-angle density cos(theta) / pi, see :func:`cosine_hemisphere_pdf`.
    """
    r, phi = _concentric_polar(u)
    w = np.empty(r.shape + (3,))
    w[..., 0] = r * np.cos(phi)
    w[..., 1] = r * np.sin(phi)
    w[..., 2] = np.sqrt(np.maximum(0.0, 1.0 - (w[..., 0] * w[..., 0] + w[..., 1] * w[..., 1])))
    return w, cosine_hemisphere_pdf(w[..., 2])


def cosine_directions(u: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(m, 3) cosine-weighted directions about unit normals n (m, 3) from uniform u (m, 2):
    ``to_world(cosine_hemisphere(u)[0], n)``, compiled when the library is there (a bake turns ~40 M: its gap
    walks, its texels' validity, its photons' bounces)."""
    lib = native_kernels.library()
    if lib is not None:
        return native_kernels.cosine_directions(lib, u, n)
    return cosine_directions_numpy(u, n)


def cosine_directions_numpy(u: np.ndarray, n: np.ndarray) -> np.ndarray:
    """:func:`cosine_directions` in numpy (the compiled kernel's reference)."""
    return to_world(cosine_hemisphere(u)[0], n)


def pattern_directions(w_local: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(m, r, 3) the r local directions ``w_local`` (r, 3) turned into the frame of each of the unit normals n
    (m, 3): ``to_world(w_local[None], n[:, None])``, compiled when the library is there (the crevice test turns
    a fixed pattern at every texel sample: 26 M directions at Sponza 16/m)."""
    lib = native_kernels.library()
    if lib is not None:
        return native_kernels.pattern_directions(lib, w_local, n)
    return pattern_directions_numpy(w_local, n)


def pattern_directions_numpy(w_local: np.ndarray, n: np.ndarray) -> np.ndarray:
    """:func:`pattern_directions` in numpy (the compiled kernel's reference)."""
    return to_world(np.asarray(w_local, np.float64)[None], np.asarray(n, np.float64)[:, None])


def cosine_hemisphere_pdf(cos_theta: np.ndarray) -> np.ndarray:
    """Solid-angle density of :func:`cosine_hemisphere`: max(cos theta, 0) / pi."""
    return np.maximum(np.asarray(cos_theta, np.float64), 0.0) / np.pi


# --------------------------------------------------------------------------- planar shapes
def concentric_disk(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Uniform points on the unit disk by Shirley and Chiu's concentric map.

    Returns
    -------
    p : (..., 2) float64 points with |p| <= 1.
    pdf : (...,) float64 area density 1 / pi.
    """
    r, phi = _concentric_polar(u)
    p = np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1)
    return p, np.full(p.shape[:-1], 1.0 / np.pi)


def _concentric_polar(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(r, phi) (...,) of :func:`concentric_disk`'s points for u (..., 2)."""
    u = np.asarray(u, dtype=np.float64)
    a = 2.0 * u[..., 0] - 1.0
    b = 2.0 * u[..., 1] - 1.0
    first = np.abs(a) > np.abs(b)
    r = np.where(first, a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(first, (np.pi / 4.0) * (b / a), (np.pi / 2.0) - (np.pi / 4.0) * (a / b))
    return r, np.where((a == 0.0) & (b == 0.0), 0.0, phi)


def uniform_triangle(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Uniform barycentrics on a triangle (square-root parametrisation).

    Returns
    -------
    bary : (..., 2) float64 Embree-style (u, v): point = (1-u-v) p0 + u p1 + v p2.
    pdf : (...,) float64 density 2 on the barycentric triangle, i.e. 1 / area on the
        real triangle (see :func:`uniform_triangle_pdf`).
    """
    u = np.asarray(u, dtype=np.float64)
    s = np.sqrt(u[..., 0])
    bary = np.stack([s * (1.0 - u[..., 1]), s * u[..., 1]], axis=-1)
    return bary, np.full(bary.shape[:-1], 2.0)


def uniform_triangle_pdf(area: np.ndarray) -> np.ndarray:
    """Area density of :func:`uniform_triangle` on a triangle of ``area``: 1 / area (0 if degenerate)."""
    area = np.asarray(area, np.float64)
    return np.divide(1.0, area, out=np.zeros_like(area), where=area > 0)


def uniform_rectangle(u: np.ndarray, size_u, size_v) -> tuple[np.ndarray, np.ndarray]:
    """Uniform points on a centred rectangle of full extents ``size_u`` x ``size_v``.

    Returns
    -------
    p : (..., 2) float64 in-plane offsets from the centre.
    pdf : (...,) float64 area density 1 / (size_u size_v).
    """
    u = np.asarray(u, dtype=np.float64)
    p = np.stack([(u[..., 0] - 0.5) * size_u, (u[..., 1] - 0.5) * size_v], axis=-1)
    return p, np.full(p.shape[:-1], 1.0 / (size_u * size_v))


def uniform_ellipse(u: np.ndarray, size_u, size_v) -> tuple[np.ndarray, np.ndarray]:
    """Uniform points on a centred ellipse with diameters ``size_u``, ``size_v`` (a scaled disk).

    Returns
    -------
    p : (..., 2) float64 in-plane offsets from the centre.
    pdf : (...,) float64 area density 4 / (pi size_u size_v).
    """
    d = concentric_disk(u)[0]
    p = d * np.array([0.5 * size_u, 0.5 * size_v])
    return p, np.full(p.shape[:-1], 4.0 / (np.pi * size_u * size_v))


# --------------------------------------------------------------------------- cones and spheres
def uniform_sphere(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Uniform directions on the unit sphere.

    Returns
    -------
    w : (..., 3) float64 unit directions.
    pdf : (...,) float64 solid-angle density 1 / (4 pi).
    """
    u = np.asarray(u, dtype=np.float64)
    z = 1.0 - 2.0 * u[..., 0]
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = 2.0 * np.pi * u[..., 1]
    w = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
    return w, np.full(w.shape[:-1], 1.0 / (4.0 * np.pi))


def uniform_cone(u: np.ndarray, one_minus_cos_max) -> tuple[np.ndarray, np.ndarray]:
    """Uniform directions in the z-up cone whose half-angle has cosine 1 - ``one_minus_cos_max``.

    Passing 1 - cos (= 2 sin^2(half/2)) rather than cos keeps a 0.27 degree sun
    accurate in float64.

    Parameters
    ----------
    u : (..., 2) uniform numbers.
    one_minus_cos_max : scalar or (...,) in (0, 2].

    Returns
    -------
    w_local : (..., 3) float64 unit directions.
    pdf : (...,) float64 solid-angle density 1 / (2 pi (1 - cos_max)), see :func:`uniform_cone_pdf`.
    """
    u = np.asarray(u, dtype=np.float64)
    omc = np.broadcast_to(np.asarray(one_minus_cos_max, np.float64), u.shape[:-1])
    one_minus_cos = u[..., 0] * omc
    cos_theta = 1.0 - one_minus_cos
    sin_theta = np.sqrt(np.maximum(0.0, one_minus_cos * (2.0 - one_minus_cos)))
    phi = 2.0 * np.pi * u[..., 1]
    w = np.stack([sin_theta * np.cos(phi), sin_theta * np.sin(phi), cos_theta], axis=-1)
    return w, uniform_cone_pdf(omc)


def uniform_cone_pdf(one_minus_cos_max) -> np.ndarray:
    """Solid-angle density of :func:`uniform_cone`: 1 / (2 pi (1 - cos_max))."""
    omc = np.asarray(one_minus_cos_max, np.float64)
    return np.divide(1.0, 2.0 * np.pi * omc, out=np.zeros_like(omc), where=omc > 0)


def sphere_cone(u: np.ndarray, p: np.ndarray, centre: np.ndarray, radius: float):
    """Directions toward a sphere, uniform in the cone it subtends from each ``p`` outside it.

    Used for a point light with a radius when it is a sphere (Blender's
    ``use_soft_falloff`` off). Every sampled direction hits the sphere.

    Parameters
    ----------
    u : (n, m, 2) uniform numbers.
    p : (n, 3) receiving points, farther than ``radius`` from ``centre``.
    centre : (3,) sphere centre; radius > 0.

    Returns
    -------
    w : (n, m, 3) float64 unit directions from ``p``.
    t : (n, m) float64 distance along ``w`` to the near side of the sphere.
    pdf : (n, m) float64 solid-angle density 1 / (2 pi (1 - cos_max)), cos_max = sqrt(1 - r^2/D^2).
    """
    delta = np.asarray(centre, np.float64) - p
    D = norms(delta)
    axis = delta / D[:, None]
    sin2 = np.minimum((radius / D) ** 2, 1.0)
    # 1 - cos for cos = sqrt(1 - sin^2), written without cancellation.
    omc = sin2 / (1.0 + np.sqrt(1.0 - sin2))
    w_local, pdf = uniform_cone(u, omc[:, None])
    w = to_world(w_local, axis[:, None, :])
    cos_theta = w_local[..., 2]
    Dm = D[:, None]
    t = Dm * cos_theta - np.sqrt(np.maximum(0.0, radius * radius - Dm * Dm * (1.0 - cos_theta * cos_theta)))
    return w, t, pdf


def disk_facing(u: np.ndarray, p: np.ndarray, centre: np.ndarray, radius: float):
    """Uniform points on the disk of ``radius`` through ``centre`` that faces each receiver ``p``.

    This is how Cycles samples a point or spot light with a radius when
    ``use_soft_falloff`` is on (Blender's default): a Lambertian disk of area
    pi r^2 whose normal points from the centre to the receiver.

    Parameters
    ----------
    u : (n, m, 2) uniform numbers.
    p : (n, 3) receiving points (not at ``centre``).
    centre : (3,) light position; radius > 0.

    Returns
    -------
    q : (n, m, 3) float64 points on the disk.
    n_disk : (n, 3) float64 unit disk normals (centre toward p).
    pdf : (n, m) float64 area density 1 / (pi r^2).
    """
    centre = np.asarray(centre, np.float64)
    delta = p - centre
    D = norms(delta, keepdims=True)
    n_disk = np.divide(delta, D, out=np.tile([0.0, 0.0, 1.0], (len(p), 1)), where=D > 0)
    t1, t2 = orthonormal_basis(n_disk)
    d, pdf = concentric_disk(u)
    q = centre + radius * (d[..., 0:1] * t1[:, None, :] + d[..., 1:2] * t2[:, None, :])
    return q, n_disk, pdf / (radius * radius)
