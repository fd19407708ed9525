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

from .lights import EMISSIVE_SIDES, scene_sphere  # noqa: F401 (re-exported)
from .scene import Scene


@dataclass(frozen=True)
class Emitter:
    kind: str  # "light", "triangles", "world"
    index: int  # light index for kind "light"
    flux: np.ndarray  # (3,) watts
    count: int
    source: object = None
    """The emitter behind the light interface (core/lights.py)."""


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


def emitter_flux(scene: Scene) -> list[Emitter]:
    """Every emitter with its flux (count 0, filled by :func:`plan`)."""
    out, lights = [], 0
    for source in scene.emitters():
        index = lights if source.photon_kind == "light" else 0
        lights += source.photon_kind == "light"
        out.append(Emitter(source.photon_kind, index, source.flux(scene), 0, source))
    return out


def plan(scene: Scene, photons: int) -> EmissionPlan:
    """Share ``photons`` among emitters in proportion to their mean-RGB flux (largest remainder)."""
    emitters = [e for e in emitter_flux(scene) if np.all(np.isfinite(e.flux)) and e.flux.mean() > 0]
    if not emitters or photons <= 0:
        return EmissionPlan(())
    weight = np.array([e.flux.mean() for e in emitters])
    share = photons * weight / weight.sum()
    counts = np.floor(share).astype(int)
    counts[np.argsort(counts - share)[: photons - counts.sum()]] += 1
    return EmissionPlan(tuple(Emitter(e.kind, e.index, e.flux, int(c), e.source) for e, c in zip(emitters, counts)
                              if c > 0))


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
        e = plan_.emitters[i]
        o, d, power, *normal = e.source.emit(scene, e.flux, e.count, count, rng)
        parts.append((o, d, power, normal[0] if normal else np.zeros_like(o)))
    return tuple(np.concatenate(c) for c in zip(*parts))
