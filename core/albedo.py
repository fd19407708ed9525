"""Diffuse albedo (linear base colour) at surface hits: constant or textured.

Photons use it for Russian roulette and the reflected power; the final
shading of a texel does not (light maps hold irradiance / pi, without colour).
Textures are sampled the way Blender's Image Texture node does with repeat
extension: pixel centres at ((i + 0.5) / W, (j + 0.5) / H), row 0 at v = 0.
"""
from __future__ import annotations

import numpy as np

from . import native_kernels
from .scene import Scene, Texture


def albedo(scene: Scene, triangles: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
    """Linear base colour at hit points.

    Parameters
    ----------
    scene : the scene (materials, textures, per-corner texture UVs).
    triangles : (n,) int64 triangle indices into ``scene.geometry``.
    barycentric : (n, 2) float64 Embree (u, v): hit = (1-u-v) p0 + u p1 + v p2.

    Returns
    -------
    (n, 3) float32 albedo in [0, 1] (textures are clipped to [0, 1] too, so a
    bright HDR texel cannot make a photon gain energy).
    """
    triangles = np.asarray(triangles, dtype=np.int64)
    barycentric = np.asarray(barycentric, dtype=np.float64)
    if len(triangles) and (triangles.min() < 0 or triangles.max() >= scene.geometry.count):
        raise IndexError(f"albedo: triangle index out of range [0, {scene.geometry.count})")
    lib = native_kernels.library()
    if lib is not None and all(t.interpolation in ("Linear", "Closest") for t in scene.textures):
        return native_kernels.albedo(lib, scene, triangles, barycentric)
    return albedo_numpy(scene, triangles, barycentric)  # which names a texture of another interpolation


def albedo_numpy(scene: Scene, triangles: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
    """:func:`albedo` in numpy for triangle indices in range (the fallback of :mod:`core.native_kernels`,
    and its reference)."""
    material = scene.geometry.material[triangles]
    out = scene.materials.base_color.astype(np.float32, copy=False)[material]
    texture = scene.materials.texture[material]
    textured = np.flatnonzero(texture >= 0)
    if len(textured) == 0:
        return out
    # Hits grouped by texture with one sort (a mask per texture costs hits x textures).
    # Few textures: a stable sort of 16-bit keys is numpy's radix sort, linear in the hits.
    key_type = np.int16 if len(scene.textures) < 2 ** 15 else np.int64
    textured = textured[np.argsort(texture[textured].astype(key_type), kind="stable")]
    keys = texture[textured]
    starts = np.flatnonzero(np.concatenate([[True], keys[1:] != keys[:-1]]))
    uv_corner = np.take(scene.geometry.uvs, triangles[textured], axis=0).astype(np.float64)  # (s, 3, 2)
    b = np.take(barycentric, textured, axis=0)
    u, v = b[:, 0:1], b[:, 1:2]
    uv = (1.0 - u - v) * uv_corner[:, 0]
    uv += u * uv_corner[:, 1]
    uv += v * uv_corner[:, 2]
    for start, stop in zip(starts, [*starts[1:], len(textured)]):
        out[textured[start:stop]] = np.clip(read_texture(scene.textures[keys[start]], uv[start:stop], None), 0.0, 1.0)
    return out


def sample_texture(texture: Texture, uv: np.ndarray) -> np.ndarray:
    """Texture colour at texture coordinates with repeat wrapping.

    Parameters
    ----------
    texture : the image; ``interpolation`` "Linear" (bilinear) or "Closest".
    uv : (n, 2) float64 texture coordinates (any real values; the image repeats).

    Returns
    -------
    (n, 3) float32 linear colour.
    """
    return read_texture(texture, uv, native_kernels.library())


def read_texture(texture: Texture, uv: np.ndarray, lib) -> np.ndarray:
    """:func:`sample_texture` with the compiled kernels ``lib``, or in numpy (None)."""
    px = texture.pixels
    H, W = px.shape[:2]
    uv = np.nan_to_num(np.asarray(uv, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    if texture.interpolation == "Closest":
        i = np.floor(uv[:, 0] * W).astype(np.int64) % W
        j = np.floor(uv[:, 1] * H).astype(np.int64) % H
        return px[j, i]
    if texture.interpolation != "Linear":
        raise ValueError(f"texture {texture.name!r}: unsupported interpolation {texture.interpolation!r}")
    if lib is not None and px.dtype == np.float32:
        return native_kernels.bilinear_rgb(lib, px, uv)
    return bilinear_numpy(px, uv)


def bilinear_numpy(px: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear between the four nearest pixel centres of image px (H, W, 3) at finite uv (n, 2), repeating
    (:func:`sample_texture`'s; :func:`core.native_kernels.bilinear_rgb` compiled)."""
    H, W = px.shape[:2]
    x = uv[:, 0] * W
    y = uv[:, 1] * H
    x -= 0.5
    y -= 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = (x - x0)[:, None].astype(np.float32)
    fy = (y - y0)[:, None].astype(np.float32)
    i0 = x0.astype(np.int64) % W
    j0 = y0.astype(np.int64) % H
    i1 = (i0 + 1) % W
    j1 = (j0 + 1) % H
    # Rows of the flattened image: np.take of one row index per neighbour is several times cheaper
    # than indexing by (j, i) pairs.
    # Pixels as single 12-byte items: a 1-D take of them is cheaper than a take of (3,) rows.
    pixel = np.ascontiguousarray(px).reshape(H * W, 3).view(np.dtype((np.void, 3 * px.itemsize))).ravel()
    row0, row1 = j0 * W, j1 * W

    def at(rows):
        return np.take(pixel, rows).view(px.dtype).reshape(-1, 3)

    gx = 1 - fx
    bottom = at(row0 + i0) * gx
    bottom += at(row0 + i1) * fx
    top = at(row1 + i0) * gx
    top += at(row1 + i1) * fx
    bottom *= 1 - fy
    top *= fy
    bottom += top
    return bottom
