"""Photon emission: how many photons each light gets, and where they start.

Photons are shared among emitters in proportion to their flux (the mean of the
RGB watts), so each photon carries about the same power. Fluxes in Blender's
units (DEVELOPERS.md):

==============  ==========================================  ===========================
emitter         flux Phi                                     directions
==============  ==========================================  ===========================
point           P                                           uniform sphere
spot            P/(4 pi) * integral of the cone attenuation  uniform in the cone, weighted
sun             S * pi R^2 (disc of the bounding sphere)     parallel (cone if angle > 0)
area            pi * L * A                                  cosine about the normal
emissive tri    pi * L * A per emitting side                 cosine about the normal
world           4 pi^2 R^2 L (uniform sphere of radiance)    inward from a far disc
==============  ==========================================  ===========================
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .direct import spot_attenuation
from .sampling import concentric_disk, cosine_hemisphere, orthonormal_basis, uniform_cone, uniform_sphere, uniform_triangle
from .scene import AreaLight, PointLight, Scene, SpotLight, SunLight

# Emitted photons start this far outside the bounding sphere (sun, world), as a
# fraction of its radius, so no surface lies behind their origin.
_OUTSIDE = 1.01
# Spot cones are integrated with this many theta steps to get their flux.
_SPOT_STEPS = 2048


@dataclass(frozen=True)
class Emitter:
    kind: str  # "light", "triangles", "world"
    index: int  # light index for kind "light"
    flux: np.ndarray  # (3,) watts
    count: int


@dataclass(frozen=True)
class EmissionPlan:
    emitters: tuple

    @property
    def total(self) -> int:
        return sum(e.count for e in self.emitters)

    def batches(self, size: int) -> list:
        """Split into batches of at most ``size`` photons: lists of (emitter index, count, first)."""
        out, current, room = [], [], size
        for i, e in enumerate(self.emitters):
            first, left = 0, e.count
            while left > 0:
                take = min(left, room)
                current.append((i, take, first))
                first += take
                left -= take
                room -= take
                if room == 0:
                    out.append((self, current))
                    current, room = [], size
        if current:
            out.append((self, current))
        return out

    def per_light(self) -> dict:
        names = {}
        for e in self.emitters:
            names[f"{e.kind}:{e.index}"] = e.count
        return names


def scene_sphere(scene: Scene) -> tuple[np.ndarray, float]:
    """Bounding sphere (centre, radius) of the geometry in scene-local coordinates."""
    p = scene.geometry.positions.reshape(-1, 3)
    if len(p) == 0:
        return np.zeros(3), 1.0
    centre = 0.5 * (p.min(0) + p.max(0))
    return centre, max(float(np.linalg.norm(p - centre, axis=1).max()), 1e-12)


def _spot_cone_integral(light: SpotLight) -> float:
    """Integral over the cone of Cycles' spot attenuation, steradians."""
    theta = np.linspace(0.0, light.half_angle, _SPOT_STEPS + 1)
    mid = 0.5 * (theta[1:] + theta[:-1])
    axis = np.asarray(light.direction, np.float64)[None]
    t1, _ = orthonormal_basis(axis)
    atten = spot_attenuation(light)(np.cos(mid)[:, None] * axis + np.sin(mid)[:, None] * t1)
    return float(np.sum(atten * np.sin(mid) * np.diff(theta)) * 2.0 * np.pi)


def emitter_flux(scene: Scene) -> list[Emitter]:
    """Every emitter with its flux (count 0, filled by :func:`plan`)."""
    _, radius = scene_sphere(scene)
    out = []
    for i, light in enumerate(scene.lights):
        if isinstance(light, PointLight):
            flux = np.asarray(light.power, np.float64)
        elif isinstance(light, SpotLight):
            flux = np.asarray(light.power, np.float64) / (4 * np.pi) * _spot_cone_integral(light)
        elif isinstance(light, SunLight):
            flux = np.asarray(light.irradiance, np.float64) * np.pi * radius ** 2
        elif isinstance(light, AreaLight):
            flux = np.asarray(light.radiance, np.float64) * np.pi * light.area
        else:
            raise TypeError(f"unknown light type {type(light).__name__}")
        out.append(Emitter("light", i, flux, 0))
    tris = scene.emissive_triangles
    if len(tris):
        L = scene.materials.emission[scene.geometry.material[tris]].astype(np.float64)
        flux = (np.pi * L * scene.geometry.areas()[tris][:, None]).sum(0) * EMISSIVE_SIDES
        out.append(Emitter("triangles", 0, flux, 0))
    if not scene.world.is_black:
        flux = np.asarray(scene.world.radiance, np.float64) * 4 * np.pi ** 2 * radius ** 2
        out.append(Emitter("world", 0, flux, 0))
    return out


EMISSIVE_SIDES = 2
"""Sides an emissive triangle emits from: Cycles mesh lights emit from both (measured: 4.9980 vs 4.9991)."""


def plan(scene: Scene, photons: int) -> EmissionPlan:
    """Share ``photons`` among emitters in proportion to their mean-RGB flux (largest remainder)."""
    emitters = [e for e in emitter_flux(scene) if np.all(np.isfinite(e.flux)) and e.flux.mean() > 0]
    if not emitters or photons <= 0:
        return EmissionPlan(())
    weight = np.array([e.flux.mean() for e in emitters])
    share = photons * weight / weight.sum()
    counts = np.floor(share).astype(int)
    counts[np.argsort(counts - share)[: photons - counts.sum()]] += 1
    return EmissionPlan(tuple(Emitter(e.kind, e.index, e.flux, int(c)) for e, c in zip(emitters, counts) if c > 0))


def emit(scene: Scene, batch, rng: np.random.Generator
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Origins, directions, powers and origin normals (m, 3) float64 of one batch.

    The origin normal is the emitting surface's normal on the side the photon
    leaves by (zero for free-space origins: point, spot, sun, world), so the
    first ray can be pushed off the emitter instead of hitting it at t = 0.
    """
    plan_, segments = batch
    parts = []
    for i, count, _ in segments:
        o, d, power, *normal = _emit_one(scene, plan_.emitters[i], count, rng)
        parts.append((o, d, power, normal[0] if normal else np.zeros_like(o)))
    return tuple(np.concatenate(c) for c in zip(*parts))


def _emit_one(scene: Scene, e: Emitter, m: int, rng: np.random.Generator):
    power = np.broadcast_to(e.flux / e.count, (m, 3)).copy()
    if e.kind == "light":
        light = scene.lights[e.index]
        if isinstance(light, PointLight):
            d = uniform_sphere(rng.random((m, 2)))[0]
            return np.broadcast_to(light.position, (m, 3)).astype(np.float64), d, power
        if isinstance(light, SpotLight):
            local, _ = uniform_cone(rng.random((m, 2)), 1.0 - np.cos(light.half_angle))
            axis = np.broadcast_to(np.asarray(light.direction, np.float64), (m, 3))
            t1, t2 = orthonormal_basis(axis)
            d = local[:, :1] * t1 + local[:, 1:2] * t2 + local[:, 2:3] * axis
            # Uniform in the cone: photon power = I * atten * Omega / n, with the plan's flux = I * integral(atten).
            omega = 2 * np.pi * (1 - np.cos(light.half_angle))
            atten = spot_attenuation(light)(d)
            integral = _spot_cone_integral(light)
            power *= (atten * omega / max(integral, 1e-300))[:, None]
            return np.broadcast_to(light.position, (m, 3)).astype(np.float64), d, power
        if isinstance(light, SunLight):
            centre, radius = scene_sphere(scene)
            toward = np.broadcast_to(np.asarray(light.direction, np.float64), (m, 3))
            if light.half_angle > 0:
                local, _ = uniform_cone(rng.random((m, 2)), 2.0 * np.sin(0.5 * light.half_angle) ** 2)
                t1, t2 = orthonormal_basis(toward)
                toward = local[:, :1] * t1 + local[:, 1:2] * t2 + local[:, 2:3] * toward
            axis = np.broadcast_to(np.asarray(light.direction, np.float64), (m, 3))
            t1, t2 = orthonormal_basis(axis)
            disc = concentric_disk(rng.random((m, 2)))[0] * radius
            o = centre + axis * radius * _OUTSIDE + disc[:, :1] * t1 + disc[:, 1:2] * t2
            return o, -toward, power
        if isinstance(light, AreaLight):
            uv = concentric_disk(rng.random((m, 2)))[0] * 0.5 if light.shape in ("DISK", "ELLIPSE") else rng.random((m, 2)) - 0.5
            o = (np.asarray(light.position, np.float64) + uv[:, :1] * light.size_u * np.asarray(light.axis_u)
                 + uv[:, 1:2] * light.size_v * np.asarray(light.axis_v))
            normal = np.broadcast_to(np.asarray(light.normal, np.float64), (m, 3))
            return o, _cosine_about(normal, rng), power, normal
    if e.kind == "triangles":
        tris = scene.emissive_triangles
        L = scene.materials.emission[scene.geometry.material[tris]].astype(np.float64)
        weight = L.mean(1) * scene.geometry.areas()[tris]
        cdf = np.cumsum(weight) / weight.sum()
        pick = tris[np.minimum(np.searchsorted(cdf, rng.random(m)), len(tris) - 1)]
        # Picked with probability w_t / W (w_t = mean(L_t) A_t); power = flux_mean / n * L_t / mean(L_t).
        L_pick = scene.materials.emission[scene.geometry.material[pick]].astype(np.float64)
        power = e.flux.mean() / e.count * L_pick / np.maximum(L_pick.mean(1, keepdims=True), 1e-300)
        uv = uniform_triangle(rng.random((m, 2)))[0]
        b = np.column_stack([1.0 - uv.sum(1), uv])
        o = np.einsum("nk,nkj->nj", b, scene.geometry.positions[pick])
        normal = scene.geometry.face_normals()[pick]
        if EMISSIVE_SIDES == 2:  # each side gets half the photons
            normal = normal * np.where(rng.random(m) < 0.5, 1.0, -1.0)[:, None]
        return o, _cosine_about(normal, rng), power, normal
    if e.kind == "world":
        centre, radius = scene_sphere(scene)
        d = uniform_sphere(rng.random((m, 2)))[0]  # direction of travel
        t1, t2 = orthonormal_basis(d)
        disc = concentric_disk(rng.random((m, 2)))[0] * radius
        o = centre - d * radius * _OUTSIDE + disc[:, :1] * t1 + disc[:, 1:2] * t2
        return o, d, power
    raise ValueError(f"unknown emitter {e.kind}")


def _cosine_about(normal: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    local = cosine_hemisphere(rng.random((len(normal), 2)))[0]
    t1, t2 = orthonormal_basis(normal)
    return local[:, :1] * t1 + local[:, 1:2] * t2 + local[:, 2:3] * normal
