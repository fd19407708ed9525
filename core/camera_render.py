"""A quick look at the baked light maps: camera rays, light-map lookup, PNG. bpy-free.

Each pixel shoots one primary ray through its centre (:mod:`core.rays`); at
the closest hit the outgoing radiance of the diffuse surface is

    L_o = albedo x E / pi + L_e,

with E / pi read bilinearly from the hit object's light map at its light-map
UV, the albedo from the material's base colour or texture and L_e its
emission. Objects without a light map show only their emission; rays that
miss see the world. The image is tone-mapped like Blender's "Standard" view
(exposure, clip to [0, 1], sRGB transfer) and written as an 8-bit PNG with
nothing but ``zlib``.
"""
from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

import numpy as np

from .rays import RayCaster
from .scene import Scene


@dataclass(frozen=True)
class Camera:
    """A pinhole or orthographic camera in scene-local coordinates.

    position : (3,) float64 scene-local eye position.
    rotation : (3, 3) float64 camera-to-scene rotation; columns are the camera's
        right, up and backward axes (it looks along -column 2, as Blender's).
    half_width, half_height : perspective: tan of half the field of view
        horizontally/vertically; orthographic: half the frame size, scene units.
    orthographic : True for an orthographic camera.
    """

    position: np.ndarray
    rotation: np.ndarray
    half_width: float
    half_height: float
    orthographic: bool = False

    def rays(self, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        """Origins and unit directions, (height*width, 3) float64 each; row 0 is the top of the image."""
        x = (np.arange(width) + 0.5) / width * 2.0 - 1.0
        y = 1.0 - (np.arange(height) + 0.5) / height * 2.0
        xx, yy = np.meshgrid(x * self.half_width, y * self.half_height)
        R = np.asarray(self.rotation, np.float64)
        eye = np.asarray(self.position, np.float64)
        if self.orthographic:
            offset = np.stack([xx, yy, np.zeros_like(xx)], -1).reshape(-1, 3) @ R.T
            origins = eye + offset
            directions = np.broadcast_to(-R[:, 2], origins.shape).copy()
        else:
            d = np.stack([xx, yy, -np.ones_like(xx)], -1).reshape(-1, 3) @ R.T
            directions = d / np.linalg.norm(d, axis=1, keepdims=True)
            origins = np.broadcast_to(eye, directions.shape).copy()
        return origins, directions


def bilinear(image: np.ndarray, uv: np.ndarray, wrap: bool = False) -> np.ndarray:
    """Sample (H, W, C) ``image`` (row 0 = bottom) at (n, 2) UVs in [0, 1]; returns (n, C) float32.

    Texel centres sit at (i + 0.5) / W; ``wrap`` repeats the image, else edges are clamped.
    """
    h, w = image.shape[:2]
    x = np.asarray(uv[:, 0], np.float64) * w - 0.5
    y = np.asarray(uv[:, 1], np.float64) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)

    def fetch(xi, yi):
        if wrap:
            xi, yi = np.mod(xi, w), np.mod(yi, h)
        else:
            xi, yi = np.clip(xi, 0, w - 1), np.clip(yi, 0, h - 1)
        return image[yi, xi]

    top = fetch(x0, y0 + 1) * (1 - fx) + fetch(x0 + 1, y0 + 1) * fx
    bottom = fetch(x0, y0) * (1 - fx) + fetch(x0 + 1, y0) * fx
    return (bottom * (1 - fy) + top * fy).astype(np.float32)


def lightmap_uvs(target, triangle_count: int, tri: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(n, 2) light-map UVs of points on ``target``'s triangles: tri (n,) scene triangle indices (all
    the target's), weights (n, 3, 1) their corner weights (1 - u - v, u, v of a hit's barycentrics)."""
    local = np.full(triangle_count, -1, np.int64)
    local[target.triangles] = np.arange(len(target.triangles))
    return (target.lightmap_uv[local[tri]] * weights).sum(axis=1)


def render_preview(scene: Scene, lightmaps: dict, camera: Camera, width: int, height: int,
                   caster: RayCaster | None = None) -> np.ndarray:
    """Linear radiance seen by ``camera`` lit only by the light maps.

    Parameters
    ----------
    scene : the baked scene (scene-local coordinates).
    lightmaps : target name -> (H, W, 4) float32 light map (RGB = E / pi, row 0 bottom).
    camera : :class:`Camera` in the same scene-local space.
    width, height : image size in pixels (typical 320-960).

    Returns
    -------
    (height, width, 3) float32 linear RGB radiance, row 0 = top.
    """
    if width < 1 or height < 1:
        raise ValueError(f"preview size {width}x{height} is empty")
    g, m = scene.geometry, scene.materials
    caster = caster or RayCaster(g.positions, scene.extent, transmission=g.transmission)
    origins, directions = camera.rays(width, height)
    hits = caster.intersect(origins, directions)
    radiance = np.broadcast_to(np.asarray(scene.world.radiance, np.float32), (len(origins), 3)).copy()
    hit = np.flatnonzero(hits.hit)
    if len(hit):
        tri = hits.triangle[hit]
        u, v = hits.barycentric[hit, 0:1], hits.barycentric[hit, 1:2]
        weights = np.stack([1.0 - u - v, u, v], axis=1)  # (n, 3, 1) corner weights
        material = g.material[tri]
        # albedo: constant base colour or texture at the material UVs
        albedo = m.base_color[material].astype(np.float32)
        for t_index, texture in enumerate(scene.textures):
            sel = np.flatnonzero(m.texture[material] == t_index)
            if len(sel):
                uv = (g.uvs[tri[sel]] * weights[sel]).sum(axis=1)
                albedo[sel] = bilinear(texture.pixels, uv, wrap=True)
        color = m.emission[material].astype(np.float32)
        # E / pi from each target's light map at the light-map UV of the hit
        for k, target in enumerate(scene.targets):
            sel = np.flatnonzero(g.target[tri] == k)
            image = lightmaps.get(target.name)
            if len(sel) == 0 or image is None:
                continue
            uv = lightmap_uvs(target, g.count, tri[sel], weights[sel])
            color[sel] += albedo[sel] * bilinear(np.asarray(image)[..., :3], uv)
        radiance[hit] = color
    radiance = np.nan_to_num(radiance, nan=0.0, posinf=0.0, neginf=0.0)
    return radiance.reshape(height, width, 3).astype(np.float32)


def tone_map(radiance: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """Blender's "Standard" view: scale by 2**exposure, clip to [0, 1], sRGB encode; (..., 3) uint8."""
    x = np.clip(np.asarray(radiance, np.float64) * 2.0 ** exposure, 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    return np.round(srgb * 255.0).astype(np.uint8)


def write_png(path, rgb: np.ndarray) -> None:
    """Write (H, W, 3) uint8 ``rgb`` (row 0 = top) as an 8-bit RGB PNG."""
    rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"write_png: expected (H, W, 3) uint8, got {rgb.shape}")
    h, w, _ = rgb.shape
    raw = np.concatenate([np.zeros((h, 1), np.uint8), rgb.reshape(h, w * 3)], axis=1).tobytes()

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))
    with open(path, "wb") as f:
        f.write(png)
