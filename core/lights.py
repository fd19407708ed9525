"""Light sources behind one interface: photon emission, shadow-ray sampling and power.

Each emitter type (point, spot, sun, area, emissive mesh, world) is a class with

- ``power(scene)`` -> (3,) float64 flux in watts (shares the photon budget, :mod:`core.emission`);
- ``emit(scene, flux, count, m, rng)`` -> m photons (origins, directions, powers (m, 3) float64,
  and origin normals for surface emitters), ``count`` photons sharing ``flux`` in all;
- ``sample_toward(caster, p, n_s, n_g, samples, rng)`` -> :class:`ShadowSamples` toward the
  light from receiving points p (n, 3), each weighted by radiance x cosines / pdf, or None when
  the light sends nothing (no power): :mod:`core.direct` traces them.

The four lamp types are the extraction's dataclasses (``pdic_addon.extract_lights`` builds them;
``core.scene`` re-exports them); :class:`EmissiveMesh` and :class:`World` are built by
:meth:`core.scene.Scene.emitters`. Conventions in Blender's units (DEVELOPERS.md); all light
colours are linear RGB multiplied into the power; directions are unit vectors in scene-local
space; every light emits from the side it faces.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from . import native_kernels, sampling
from .sampling import concentric_disk, cosine_hemisphere, orthonormal_basis, uniform_cone, uniform_sphere, uniform_triangle
from .portals import Portals, mixture_power, through_portals
from .vectors import dots, norms, unit

if TYPE_CHECKING:  # rays imports scene, which imports this module
    from .rays import RayCaster


class SceneError(ValueError):
    """Bad input that makes a bake impossible; the message names the culprit."""


LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
"""Rec. 709 luminance of linear RGB (Blender's default scene-linear space): emitter selection weights."""
EMISSIVE_KEY = "<emissive triangles>"
"""Key of the emissive-mesh entry in DirectResult.skipped (lights are keyed by name)."""
WORLD_KEY = "<world>"
AREA_SHAPES = ("SQUARE", "RECTANGLE", "DISK", "ELLIPSE")
EMISSIVE_SIDES = 2
"""Sides an emissive triangle emits from: Cycles mesh lights emit from both (measured: 4.9980 vs 4.9991)."""
OUTSIDE = 1.01
"""Emitted photons of the sun and world start this far outside the bounding sphere (a fraction of
its radius), so no surface lies behind their origin."""
SPOT_STEPS = 2048
"""Theta steps of the spot cone's flux integral."""


@dataclass(frozen=True)
class ShadowSamples:
    """Shadow-ray samples toward one emitter from k receiving points, m samples each.

    kind : light kind (``core.direct.LIGHT_KINDS``), key : the light's name (skipped-point counter).
    idx : (k,) receiving point indices. weight : (k, m) radiance x cosines / pdf (colour apart).
    ok : (k, m) samples worth a ray. colour : (3,) or per sample (k, m, 3).
    samples : the estimator's divisor. targets : (k, m, 3) points on the emitter, or
    directions : (k, m, 3) for rays to infinity (sun, world). exact : the samples are no draw but
    the emitter itself (one ray to a point light of radius 0 or along a sun of angle 0): their
    visibility is the point's lit share, not an estimate of it.
    """

    kind: str
    key: str
    idx: np.ndarray
    targets: np.ndarray | None
    weight: np.ndarray
    ok: np.ndarray
    colour: np.ndarray
    samples: int
    directions: np.ndarray | None = None
    exact: bool = False


def _samples(kind, key, caster, idx, p, n_g, targets, weight, ok, colour, samples, directions=None, exact=False):
    return ShadowSamples(kind, key, idx, targets, weight, ok, colour, samples, directions, exact)


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def _rgb(value, name) -> np.ndarray:
    c = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,))
    if not np.isfinite(c).all():
        raise SceneError(f"light {name!r}: non-finite power/colour {c}")
    return c


def _even_power(flux: np.ndarray, count: int, m: int) -> np.ndarray:
    """(m, 3) watts per photon when ``count`` photons share ``flux`` evenly."""
    return np.broadcast_to(flux / count, (m, 3)).copy()


def _cosine_about(normal: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    local = cosine_hemisphere(rng.random((len(normal), 2)))[0]
    t1, t2 = orthonormal_basis(normal)
    return local[:, :1] * t1 + local[:, 1:2] * t2 + local[:, 2:3] * normal


def scene_sphere(scene) -> tuple[np.ndarray, float]:
    """Bounding sphere (centre, radius) of the geometry in scene-local coordinates."""
    p = scene.geometry.positions.reshape(-1, 3)
    if len(p) == 0:
        return np.zeros(3), 1.0
    centre = 0.5 * (p.min(0) + p.max(0))
    return centre, max(float(np.linalg.norm(p - centre, axis=1).max()), 1e-12)


def unused_portals(scene) -> list[str]:
    """Names of ``scene.portals`` the sun's and the world's photons are not sent through (deviation
    portal-photons): without area, or reaching outside the scene's bounding sphere (:meth:`Portals.usable`)."""
    if not scene.portals:
        return []
    centre, radius = scene_sphere(scene)
    return [p.name for p in scene.portals if not Portals.usable(p, centre, radius)]


class _Lamp:
    """What the four lamp types share: they emit when their colour quantity is positive somewhere."""

    photon_kind = "light"
    colour_field = "power"

    def emits(self) -> bool:
        return bool(np.any(np.asarray(getattr(self, self.colour_field)) > 0))


@dataclass(frozen=True)
class PointLight(_Lamp):
    """Point light; with ``radius`` > 0 a sphere light (Blender's soft radius).

    power : (3,) watts per channel. Irradiance at distance d facing it: P / (4 pi d^2).
    """

    name: str
    position: np.ndarray
    power: np.ndarray
    radius: float = 0.0
    soft_falloff: bool = True
    """Blender's Soft Falloff: with a radius, a Lambertian disc facing the receiver (on) or a sphere (off)."""

    def flux(self, scene) -> np.ndarray:
        return np.asarray(self.power, np.float64)

    def emit(self, scene, flux, count, m, rng):
        """Uniform over the sphere of directions, from the light's position."""
        power = _even_power(flux, count, m)
        d = uniform_sphere(rng.random((m, 2)))[0]
        return np.broadcast_to(self.position, (m, 3)).astype(np.float64), d, power

    def sample_toward(self, caster, p, n_s, n_g, samples, rng):
        return _point_like("point", self, None, caster, p, n_s, n_g, samples, rng)

    @property
    def hard(self) -> bool:
        """Radius 0: one exact shadow ray per point, :meth:`shadow_rays` (without its (k, 1) samples)."""
        return max(float(self.radius), 0.0) == 0.0

    def shadow_rays(self, p, n_s, n_g, epsilon: float) -> tuple:
        """:func:`point_light_rays` toward this light (of radius 0) from points p with normals n_s, n_g."""
        return point_light_rays(p, n_s, n_g, np.asarray(self.position, np.float64), epsilon)


@dataclass(frozen=True)
class SpotLight(_Lamp):
    """Spot light: a point light masked by a cone (power is that of the full sphere, as Blender).

    direction : (3,) unit axis of the cone.
    half_angle : radians, half of Blender's ``spot_size``.
    blend : [0, 1], Blender's ``spot_blend`` (smoothstep edge width).
    """

    name: str
    position: np.ndarray
    direction: np.ndarray
    power: np.ndarray
    half_angle: float
    blend: float
    radius: float = 0.0
    soft_falloff: bool = True

    def flux(self, scene) -> np.ndarray:
        """P / (4 pi) x the integral of the cone attenuation over the cone."""
        return np.asarray(self.power, np.float64) / (4 * np.pi) * _spot_cone_integral(self)

    def emit(self, scene, flux, count, m, rng):
        """Uniform in the cone, weighted by the attenuation: power = I atten Omega / n."""
        power = _even_power(flux, count, m)
        local, _ = uniform_cone(rng.random((m, 2)), 1.0 - np.cos(self.half_angle))
        axis = np.broadcast_to(np.asarray(self.direction, np.float64), (m, 3))
        t1, t2 = orthonormal_basis(axis)
        d = local[:, :1] * t1 + local[:, 1:2] * t2 + local[:, 2:3] * axis
        # The plan's flux = I * integral(atten).
        omega = 2 * np.pi * (1 - np.cos(self.half_angle))
        atten = spot_attenuation(self)(d)
        integral = _spot_cone_integral(self)
        power *= (atten * omega / max(integral, 1e-300))[:, None]
        return np.broadcast_to(self.position, (m, 3)).astype(np.float64), d, power

    def sample_toward(self, caster, p, n_s, n_g, samples, rng):
        return _point_like("spot", self, spot_attenuation(self), caster, p, n_s, n_g, samples, rng)


@dataclass(frozen=True)
class SunLight(_Lamp):
    """Directional light. ``direction`` points *from* the scene *towards* the sun.

    irradiance : (3,) W/m^2 on a surface facing the sun (Blender's strength x colour).
    half_angle : radians, half of Blender's ``angle`` (angular diameter).
    """

    name: str
    direction: np.ndarray
    irradiance: np.ndarray
    half_angle: float = 0.0

    colour_field = "irradiance"

    def flux(self, scene) -> np.ndarray:
        """S x the cross-section of the scene's bounding sphere."""
        _, radius = scene_sphere(scene)
        return np.asarray(self.irradiance, np.float64) * np.pi * radius ** 2

    def emit(self, scene, flux, count, m, rng):
        """Parallel rays (a cone with an angle) from a disc just outside the bounding sphere."""
        power = _even_power(flux, count, m)
        centre, radius = scene_sphere(scene)
        toward = np.broadcast_to(np.asarray(self.direction, np.float64), (m, 3))
        if self.half_angle > 0:
            local, _ = uniform_cone(rng.random((m, 2)), 2.0 * np.sin(0.5 * self.half_angle) ** 2)
            t1, t2 = orthonormal_basis(toward)
            toward = local[:, :1] * t1 + local[:, 1:2] * t2 + local[:, 2:3] * toward
        axis = np.broadcast_to(np.asarray(self.direction, np.float64), (m, 3))
        t1, t2 = orthonormal_basis(axis)
        disc = concentric_disk(rng.random((m, 2)))[0] * radius
        o = centre + axis * radius * OUTSIDE + disc[:, :1] * t1 + disc[:, 1:2] * t2
        portals = Portals.of(scene, centre, radius) if scene.portals else None
        if portals is None:
            return o, -toward, power
        return self._through_portals(portals, o, -toward, power, centre, radius, rng)

    def _through_portals(self, portals, o, d, power, centre, radius, rng):
        """Deviation portal-photons (:mod:`core.portals`): a share of the lines through the portals the sun
        shines into (chosen by area x cosine), each line weighted by the mixture's density."""
        axis = np.asarray(self.direction, np.float64)
        weight = portals.area * np.maximum(portals.normal @ -axis, 0.0)
        if weight.sum() <= 0:
            return o, d, power
        chance = weight / weight.sum()
        rows, j, x = portals.pick(len(o), chance, rng)
        through_portals(o, d, rows, x, centre, radius * OUTSIDE, facing=-axis)  # the disc across the sun's axis
        crossed, cos = portals.crossed(o, d)
        # disc lines per unit area across the line: 1 / (pi R^2 |d . axis|); portal lines: chance / (A |cos|)
        ratio = np.pi * radius ** 2 * np.abs(d @ axis) * (crossed * chance / (portals.area * np.maximum(np.abs(cos), 1e-12))).sum(axis=1)
        return o, d, mixture_power(power, ratio)

    def sample_toward(self, caster, p, n_s, n_g, samples, rng):
        return _sun(self, caster, p, n_s, n_g, samples, rng)


@dataclass(frozen=True)
class AreaLight(_Lamp):
    """One-sided area light emitting along ``normal`` with uniform radiance.

    shape : "SQUARE", "RECTANGLE", "DISK" or "ELLIPSE".
    axis_u, axis_v : (3,) unit in-plane axes; ``size_u``, ``size_v`` the full extents
        (diameters for DISK/ELLIPSE) in scene units.
    radiance : (3,) W/m^2/sr; Blender's power P gives radiance P / (pi * area).
    """

    name: str
    position: np.ndarray
    normal: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    size_u: float
    size_v: float
    shape: str
    radiance: np.ndarray

    @property
    def area(self) -> float:
        if self.shape in ("DISK", "ELLIPSE"):
            return float(np.pi * 0.25 * self.size_u * self.size_v)
        return float(self.size_u * self.size_v)

    colour_field = "radiance"

    def flux(self, scene) -> np.ndarray:
        return np.asarray(self.radiance, np.float64) * np.pi * self.area

    def emit(self, scene, flux, count, m, rng):
        """Uniform over the surface, cosine-distributed about the normal."""
        power = _even_power(flux, count, m)
        if self.shape in ("DISK", "ELLIPSE"):
            uv = concentric_disk(rng.random((m, 2)))[0] * 0.5
        else:
            uv = rng.random((m, 2)) - 0.5
        o = (np.asarray(self.position, np.float64) + uv[:, :1] * self.size_u * np.asarray(self.axis_u)
             + uv[:, 1:2] * self.size_v * np.asarray(self.axis_v))
        normal = np.broadcast_to(np.asarray(self.normal, np.float64), (m, 3))
        return o, _cosine_about(normal, rng), power, normal

    def sample_toward(self, caster, p, n_s, n_g, samples, rng):
        return _area(self, caster, p, n_s, n_g, samples, rng)


@dataclass(frozen=True)
class World:
    """Uniform environment: radiance (3,) W/m^2/sr. An unoccluded surface receives E = pi * radiance."""

    radiance: np.ndarray = field(default_factory=lambda: np.zeros(3, np.float32))

    @property
    def is_black(self) -> bool:
        return not np.any(np.asarray(self.radiance) > 0)

    name = WORLD_KEY
    photon_kind = "world"

    def emits(self) -> bool:
        return not self.is_black

    def flux(self, scene) -> np.ndarray:
        """4 pi^2 R^2 L: a uniform sphere of radiance around the bounding sphere."""
        _, radius = scene_sphere(scene)
        return np.asarray(self.radiance, np.float64) * 4 * np.pi ** 2 * radius ** 2

    def emit(self, scene, flux, count, m, rng):
        """Inward from a disc just outside the bounding sphere, in uniform directions."""
        power = _even_power(flux, count, m)
        centre, radius = scene_sphere(scene)
        d = uniform_sphere(rng.random((m, 2)))[0]  # direction of travel
        t1, t2 = orthonormal_basis(d)
        disc = concentric_disk(rng.random((m, 2)))[0] * radius
        o = centre - d * radius * OUTSIDE + disc[:, :1] * t1 + disc[:, 1:2] * t2
        portals = Portals.of(scene, centre, radius) if scene.portals else None
        if portals is None:
            return o, d, power
        # deviation: portal-photons (core/portals.py): a share of the lines through the portals (chosen by
        # area), cosine-weighted inward; disc lines per unit area and solid angle 1 / (4 pi^2 R^2), portal
        # lines 1 / (pi A_total) for each portal the line enters by.
        rows, j, x = portals.pick(m, portals.area / portals.area.sum(), rng)
        d[rows] = _cosine_about(portals.normal[j], rng)
        through_portals(o, d, rows, x, centre, radius * OUTSIDE)
        crossed, cos = portals.crossed(o, d)
        ratio = 4.0 * np.pi * radius ** 2 * (crossed & (cos > 0)).sum(axis=1) / portals.area.sum()
        return o, d, mixture_power(power, ratio)

    def sample_toward(self, caster, p, n_s, n_g, samples, rng):
        return _world(self, caster, p, n_s, n_g, samples, rng)


@dataclass(frozen=True)
class EmissiveMesh:
    """Every emissive triangle of the scene as one emitter (two-sided, as Cycles' mesh lights).

    geometry, materials : the scene's :class:`~core.scene.Geometry` and :class:`~core.scene.Materials`.
    triangles : (e,) int64 indices of the emissive triangles (``Scene.emissive_triangles``).
    """

    geometry: object
    materials: object
    triangles: np.ndarray

    name = EMISSIVE_KEY
    photon_kind = "triangles"

    def emits(self) -> bool:
        return len(self.triangles) > 0

    def _radiance(self, tris) -> np.ndarray:
        return self.materials.emission[self.geometry.material[tris]].astype(np.float64)

    def flux(self, scene) -> np.ndarray:
        """pi L A per triangle and emitting side, summed."""
        tris = self.triangles
        L = self._radiance(tris)
        return (np.pi * L * self.geometry.areas()[tris][:, None]).sum(0) * EMISSIVE_SIDES

    def emit(self, scene, flux, count, m, rng):
        """Triangles picked by mean radiance x area, uniform on each, cosine about a random side."""
        tris = self.triangles
        L = self._radiance(tris)
        weight = L.mean(1) * self.geometry.areas()[tris]
        cdf = np.cumsum(weight) / weight.sum()
        pick = tris[np.minimum(np.searchsorted(cdf, rng.random(m)), len(tris) - 1)]
        # Picked with probability w_t / W (w_t = mean(L_t) A_t); power = flux_mean / n * L_t / mean(L_t).
        L_pick = self._radiance(pick)
        power = flux.mean() / count * L_pick / np.maximum(L_pick.mean(1, keepdims=True), 1e-300)
        uv = uniform_triangle(rng.random((m, 2)))[0]
        b = np.column_stack([1.0 - uv.sum(1), uv])
        o = np.einsum("nk,nkj->nj", b, self.geometry.positions[pick])
        normal = self.geometry.face_normals()[pick]
        if EMISSIVE_SIDES == 2:  # each side gets half the photons
            normal = normal * np.where(rng.random(m) < 0.5, 1.0, -1.0)[:, None]
        return o, _cosine_about(normal, rng), power, normal

    def sample_toward(self, caster, p, n_s, n_g, samples, rng):
        return _emissive(self, caster, p, n_s, n_g, samples, rng)

Light = PointLight | SpotLight | SunLight | AreaLight
"""The lamp types of ``Scene.lights`` (emissive meshes and the world come from materials and
``Scene.world``)."""


# --------------------------------------------------------------------------- shadow-ray sampling
def point_light_rays(p: np.ndarray, n_s: np.ndarray, n_g: np.ndarray, c: np.ndarray, epsilon: float) -> tuple:
    """The shadow rays toward a point light of radius 0 at c (3,) from points p with unit normals n_s, n_g
    (m, 3), as :func:`_point_like` samples it and :meth:`RayCaster.transmittance_between` casts: (rows (k,)
    the points lit at a positive weight, weight (k,) cos_s / (4 pi d^2), start (k, 3) each ray's origin
    pushed ``epsilon`` off its surface, directions (k, 3) unit (0 for a zero-length segment), t_max (k,),
    open (k,) bool: a positive length). Compiled (:mod:`core.native_kernels`) when the library is there."""
    lib = native_kernels.library()
    if lib is not None:
        return native_kernels.point_light_rays(lib, p, n_s, n_g, c, epsilon)
    return point_light_rays_numpy(p, n_s, n_g, c, epsilon)


def point_light_rays_numpy(p: np.ndarray, n_s: np.ndarray, n_g: np.ndarray, c: np.ndarray, epsilon: float) -> tuple:
    """:func:`point_light_rays` in numpy (the compiled kernel's reference)."""
    from .rays import shadow_segments  # here: core.rays imports core.scene, which imports this module

    delta = c - p
    D = norms(delta)
    can = np.flatnonzero((D > 0) & (dots(n_g, delta) > 0.0) & (dots(n_s, delta) > 0.0))
    d = D[can]
    w = delta[can] / d[:, None]
    cos_s = dots(n_s[can], w)
    weight = cos_s / (4.0 * np.pi * d * d)
    ok = (cos_s > 0) & (dots(n_g[can], w) > 0) & (weight > 0)
    rows = can[ok]
    return (rows, weight[ok], *shadow_segments(p[rows], n_g[rows], np.broadcast_to(c, (len(rows), 3)), epsilon))


def _point_like(kind, light, attenuation, caster, p, n_s, n_g, samples, rng):
    """Point or spot light; a radius makes it a disk facing the receiver or a sphere."""
    P = _rgb(light.power, light.name)
    c = np.asarray(light.position, np.float64)
    r = max(float(light.radius), 0.0)
    if not np.any(P > 0):
        return None
    delta = c - p
    D = norms(delta)
    # Which points can receive anything: not at the light, light not wholly below the surface,
    # inside the spot cone widened by the light's angular radius.
    can = (D > 0) & (dots(n_g, delta) > -r) & (dots(n_s, delta) > -r)  # dots: as the compiled point light
    if attenuation is not None:
        v = np.divide(-delta, D[:, None], out=np.zeros_like(delta), where=D[:, None] > 0)
        spread = np.arcsin(np.clip(np.divide(r, D, out=np.ones_like(D), where=D > 0), 0.0, 1.0))
        angle = np.arccos(np.clip(_dot(v, attenuation.axis), -1.0, 1.0))
        can &= (angle < np.arccos(np.clip(attenuation.cos_h, -1.0, 1.0)) + spread) | (D <= r)
    idx = np.flatnonzero(can)
    pk, nsk, ngk = (np.take(v, idx, axis=0) for v in (p, n_s, n_g))

    if r == 0.0:
        # E = P cos_s / (4 pi d^2) x spot mask, one shadow ray.
        d = D[idx]
        w = delta[idx] / d[:, None]
        cos_s = dots(nsk, w)
        ok = (cos_s > 0) & (dots(ngk, w) > 0)
        f = attenuation(-w) if attenuation is not None else 1.0
        weight = f * cos_s / (4.0 * np.pi * d * d)
        ok &= weight > 0
        return _samples(kind, light.name, caster, idx, p, n_g, np.broadcast_to(c, (len(idx), 1, 3)),
                     weight[:, None], ok[:, None], P, 1, exact=True)

    u = sampling.stratified_2d(len(idx), samples, rng)
    soft_falloff = bool(light.soft_falloff)
    if soft_falloff:
        # Lambertian disk facing the receiver: L = P / (4 pi^2 r^2), A = pi r^2, so
        # L cos_s cos_l / d^2 / pdf_A = P cos_s cos_l / (4 pi d^2).
        q, n_disk, _ = sampling.disk_facing(u, pk, c, r)
        weight, ok = disk_samples(q, pk, nsk, ngk, n_disk, attenuation)
        return _samples(kind, light.name, caster, idx, p, n_g, q, weight, ok, P, samples)
    weight, ok, targets = _sphere_samples(u, pk, nsk, ngk, D[idx], c, r, attenuation)
    return _samples(kind, light.name, caster, idx, p, n_g, targets, weight, ok, P, samples)


def disk_samples(q: np.ndarray, pk: np.ndarray, nsk: np.ndarray, ngk: np.ndarray, n_disk: np.ndarray,
                 attenuation=None) -> tuple[np.ndarray, np.ndarray]:
    """(weight (k, m), ok (k, m)) of a soft-falloff lamp's samples q (k, m, 3) on the disk facing each receiver
    pk (k, 3) (normal n_disk (k, 3)) with normals nsk, ngk: f cos_s cos_l / (4 pi d^2) where the sample lies above
    both normals and in front of the disk (f: the spot mask, 1 without ``attenuation``). Compiled for point lights
    where the kernels load (the same bits), else :func:`disk_samples_numpy`."""
    lib = native_kernels.library() if attenuation is None else None
    if lib is not None:
        return native_kernels.disk_samples(lib, q, pk, nsk, ngk, n_disk)
    return disk_samples_numpy(q, pk, nsk, ngk, n_disk, attenuation)


def disk_samples_numpy(q, pk, nsk, ngk, n_disk, attenuation=None) -> tuple:
    """:func:`disk_samples` in numpy (the compiled kernel's reference); dot products summed left to right."""
    w = q - pk[:, None, :]
    d = norms(w)
    w = np.divide(w, d[..., None], out=np.zeros_like(w), where=d[..., None] > 0)
    cos_s = dots(nsk[:, None, :], w)
    cos_l = -dots(n_disk[:, None, :], w)
    ok = (d > 0) & (cos_s > 0) & (dots(ngk[:, None, :], w) > 0) & (cos_l > 0)
    f = attenuation(-w) if attenuation is not None else 1.0
    weight = np.divide(f * cos_s * cos_l, 4.0 * np.pi * d * d, out=np.zeros_like(d), where=ok)
    return weight, ok & (weight > 0)


def _sphere_samples(u, pk, nsk, ngk, D, c, r, attenuation):
    """Shadow-ray samples (weight, ok (k, m), targets (k, m, 3)) toward a sphere light of radius r.

    Radiance L = P / (4 pi^2 r^2) (P applied by the caller): a uniform cone toward the sphere
    from outside (estimator L cos_s / pdf_omega); from inside, every direction of the
    hemisphere ends on it.
    """
    L = 1.0 / (4.0 * np.pi * np.pi * r * r)
    outside = D > r
    weight = np.zeros(u.shape[:2])
    ok = np.zeros(u.shape[:2], bool)
    targets = np.zeros(u.shape[:2] + (3,))
    o = np.flatnonzero(outside)
    if len(o):
        w, t, pdf = sampling.sphere_cone(u[o], pk[o], c, r)
        cos_s = _dot(nsk[o][:, None, :], w)
        good = (cos_s > 0) & (_dot(ngk[o][:, None, :], w) > 0)
        f = attenuation(-w) if attenuation is not None else 1.0
        weight[o] = np.where(good, L * f * cos_s / pdf, 0.0)
        ok[o] = good & (weight[o] > 0)
        targets[o] = pk[o][:, None, :] + t[..., None] * w
    i = np.flatnonzero(~outside)
    if len(i):
        w_local, _ = sampling.cosine_hemisphere(u[i])
        w = sampling.to_world(w_local, nsk[i][:, None, :])
        # Exit distance from inside the sphere along w.
        rel = pk[i] - c
        b = _dot(rel[:, None, :], w)
        cc = _dot(rel, rel) - r * r
        t = -b + np.sqrt(np.maximum(b * b - cc[:, None], 0.0))
        good = (_dot(ngk[i][:, None, :], w) > 0) & (t > 0)
        weight[i] = np.where(good, np.pi * L, 0.0)
        ok[i] = good
        targets[i] = pk[i][:, None, :] + t[..., None] * w
    return weight, ok, targets



def _sun(light: "SunLight", caster, p, n_s, n_g, samples, rng):
    """Sun: E = S cos_s, or a cone of half-angle a with radiance S / (pi sin^2 a)."""
    S = _rgb(light.irradiance, light.name)
    s = unit(np.asarray(light.direction, np.float64)[None])[0]
    alpha = float(np.clip(light.half_angle, 0.0, np.pi / 2))
    if not np.any(S > 0) or not np.any(s):
        return None
    sin_a = np.sin(alpha)
    can = (_dot(n_g, s) > -sin_a) & (_dot(n_s, s) > -sin_a)
    idx = np.flatnonzero(can)
    nsk, ngk = n_s[idx], n_g[idx]
    if alpha == 0.0:
        cos_s = _dot(nsk, s)
        ok = (cos_s > 0) & (_dot(ngk, s) > 0)
        directions = np.broadcast_to(s, (len(idx), 1, 3))
        return _samples("sun", light.name, caster, idx, p, n_g, None, cos_s[:, None], ok[:, None], S, 1,
                     directions=directions, exact=True)
    one_minus_cos = 2.0 * np.sin(0.5 * alpha) ** 2
    u = sampling.stratified_2d(len(idx), samples, rng)
    w_local, pdf = sampling.uniform_cone(u, one_minus_cos)
    w = sampling.to_world(w_local, s)
    cos_s = _dot(nsk[:, None, :], w)
    ok = (cos_s > 0) & (_dot(ngk[:, None, :], w) > 0)
    # L cos_s / pdf with L = S / (pi sin^2 a), sin^2 a = omc (2 - omc).
    weight = cos_s / (np.pi * one_minus_cos * (2.0 - one_minus_cos) * pdf)
    return _samples("sun", light.name, caster, idx, p, n_g, None, weight, ok, S, samples, directions=w)



def _area(light: "AreaLight", caster, p, n_s, n_g, samples, rng):
    """One-sided planar light: estimator L cos_s cos_l / d^2 / pdf_area, pdf_area = 1 / A."""
    if light.shape not in AREA_SHAPES:
        raise SceneError(f"area light {light.name!r}: unknown shape {light.shape!r} (expected one of {AREA_SHAPES})")
    L = _rgb(light.radiance, light.name)
    su, sv = float(light.size_u), float(light.size_v)
    if not np.any(L > 0) or not (su > 0 and sv > 0 and np.isfinite(su * sv)):
        return None
    c = np.asarray(light.position, np.float64)
    N = unit(np.asarray(light.normal, np.float64)[None])[0]
    U = unit(np.asarray(light.axis_u, np.float64)[None])[0]
    V = unit(np.asarray(light.axis_v, np.float64)[None])[0]
    corners = c + np.array([[a * su / 2, b * sv / 2] for a in (-1, 1) for b in (-1, 1)]) @ np.stack([U, V])
    idx = np.flatnonzero(area_facing(p, n_s, n_g, c, N, corners))
    pk, nsk, ngk = (np.take(v, idx, axis=0) for v in (p, n_s, n_g))
    u = sampling.stratified_2d(len(idx), samples, rng)
    if light.shape in ("DISK", "ELLIPSE"):
        xy, pdf_area = sampling.uniform_ellipse(u, su, sv)
    else:
        xy, pdf_area = sampling.uniform_rectangle(u, su, sv)
    # Points are in front of the light, so its normal N points toward them: the targets lift along it
    # (_lift_off_emitter). The area density is the same over the whole light.
    pdf = float(pdf_area.flat[0]) if pdf_area.size else 1.0
    targets, weight, ok = area_samples(xy, pk, nsk, ngk, c, N, U, V, pdf, 2.0 * caster.epsilon)
    return _samples("area", light.name, caster, idx, p, n_g, targets, weight, ok, L, samples)


def area_facing(p: np.ndarray, n_s: np.ndarray, n_g: np.ndarray, c, N, corners: np.ndarray) -> np.ndarray:
    """(n,) bool: points p (n, 3) in front of an area light's emitting side (centre c, normal N) with some corner of
    its bounding rectangle (``corners`` (4, 3)) above both normals n_s, n_g: the points its samples may light.
    Compiled where the kernels load (the same bits), else :func:`area_facing_numpy`."""
    lib = native_kernels.library()
    if lib is not None:
        return native_kernels.area_facing(lib, p, n_s, n_g, c, N, corners)
    return area_facing_numpy(p, n_s, n_g, c, N, corners)


def area_facing_numpy(p, n_s, n_g, c, N, corners) -> np.ndarray:
    """:func:`area_facing` in numpy (the compiled kernel's reference); dot products summed left to right."""
    front = dots(p - c, N) > 0
    to_corner = corners[None, :, :] - p[:, None, :]
    above = np.any(dots(n_g[:, None, :], to_corner) > 0, axis=1) & np.any(dots(n_s[:, None, :], to_corner) > 0, axis=1)
    return front & above


def area_samples(xy: np.ndarray, pk: np.ndarray, nsk: np.ndarray, ngk: np.ndarray, c, N, U, V, pdf_area: float,
                 lift: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(targets (k, m, 3), weight (k, m), ok (k, m)) of an area light's samples: the points ``xy`` (k, m, 2) in its
    plane (centre c, unit normal N toward the receivers, axes U, V) of constant area density ``pdf_area``, seen from
    points pk with normals nsk, ngk (k, 3): weight cos_s cos_l / (d^2 pdf_area) where the sample lies above both
    normals and the receiver before the light's face, targets lifted ``lift`` along N (:func:`_lift_off_emitter`).
    Compiled where the kernels load (the same bits), else :func:`area_samples_numpy`."""
    lib = native_kernels.library()
    if lib is not None:
        return native_kernels.area_samples(lib, xy, pk, nsk, ngk, c, N, U, V, pdf_area, lift)
    return area_samples_numpy(xy, pk, nsk, ngk, c, N, U, V, pdf_area, lift)


def area_samples_numpy(xy, pk, nsk, ngk, c, N, U, V, pdf_area: float, lift: float) -> tuple:
    """:func:`area_samples` in numpy (the compiled kernel's reference); dot products summed left to right."""
    q = c + xy[..., 0:1] * U + xy[..., 1:2] * V
    w = q - pk[:, None, :]
    d = norms(w)
    w = np.divide(w, d[..., None], out=np.zeros_like(w), where=d[..., None] > 0)
    cos_s = dots(nsk[:, None, :], w)
    cos_l = -dots(w, N)
    ok = (d > 0) & (cos_s > 0) & (cos_l > 0) & (dots(ngk[:, None, :], w) > 0)
    weight = np.divide(cos_s * cos_l, d * d * pdf_area, out=np.zeros_like(d), where=ok)
    return q + lift * N, weight, ok



def _world(world: "World", caster, p, n_s, n_g, samples, rng):
    """Uniform world: cosine-weighted rays about the shading normal, E = pi L x unoccluded fraction."""
    L = _rgb(world.radiance, "world")
    n = len(p)
    idx = np.arange(n)
    u = sampling.stratified_2d(n, samples, rng)
    w_local, _ = sampling.cosine_hemisphere(u)
    w = sampling.to_world(w_local, n_s[:, None, :])
    ok = (_dot(n_g[:, None, :], w) > 0) & np.any(n_s != 0, axis=1)[:, None]
    weight = np.full(ok.shape, np.pi)
    return _samples("world", WORLD_KEY, caster, idx, p, n_g, None, weight, ok, L, samples, directions=w)



def spot_attenuation(light: "SpotLight"):
    """Cycles' spot mask of the unit direction light -> receiver (kernel/light/spot.h).

    f = smoothstep((cos_a - cos_h) * spot_smooth), spot_smooth = 1 / ((1 - cos_h) * blend),
    smoothstep(x) = 3x^2 - 2x^3 on [0, 1]; blend 0 is the hard cone cos_a > cos_h.
    Measured against Cycles 5.0 (60 degree cone, blend 1): within 0.0006 at 1..30 degrees.
    """
    axis = unit(np.asarray(light.direction, np.float64))
    cos_h = float(np.cos(light.half_angle))
    width = (1.0 - cos_h) * float(np.clip(light.blend, 0.0, 1.0))

    def attenuation(v_light_to_p: np.ndarray) -> np.ndarray:
        cos_a = _dot(v_light_to_p, axis)
        if width <= 0.0:
            return (cos_a > cos_h).astype(np.float64)
        x = np.clip((cos_a - cos_h) / width, 0.0, 1.0)
        return x * x * (3.0 - 2.0 * x)

    attenuation.axis = axis
    attenuation.cos_h = cos_h
    return attenuation



def _lift_off_emitter(q: np.ndarray, m_toward: np.ndarray, caster: RayCaster) -> np.ndarray:
    """Move shadow-ray targets on an emitter surface 2 epsilon toward the receiver along its normal.

    ``RayCaster.visible_between`` shortens the segment by epsilon *along the ray*, but the
    origin is also pushed epsilon along the receiver's normal; for oblique rays the end then
    lands past the emitter's plane and the emitter (or a ceiling it sits on) occludes its own
    light (measured: 78 % of rays lost at 30 degrees elevation). Lifting the target along the
    emitter normal by 2 epsilon keeps the segment's end at least epsilon in front of it.
    m_toward : (..., 3) unit emitter normals oriented toward the receiver.
    """
    return q + (2.0 * caster.epsilon) * m_toward




def _spot_cone_integral(light: SpotLight) -> float:
    """Integral over the cone of Cycles' spot attenuation, steradians."""
    theta = np.linspace(0.0, light.half_angle, SPOT_STEPS + 1)
    mid = 0.5 * (theta[1:] + theta[:-1])
    axis = np.asarray(light.direction, np.float64)[None]
    t1, _ = orthonormal_basis(axis)
    atten = spot_attenuation(light)(np.cos(mid)[:, None] * axis + np.sin(mid)[:, None] * t1)
    return float(np.sum(atten * np.sin(mid) * np.diff(theta)) * 2.0 * np.pi)


def _emissive(mesh: EmissiveMesh, caster, p, n_s, n_g, samples, rng):
    """Emissive triangles, two-sided (as Cycles), picked by area x luminance of their radiance."""
    tri = mesh.triangles
    g = mesh.geometry
    Le = mesh._radiance(tri)  # (e, 3)
    area = g.areas()[tri]
    weight_tri = area * (Le @ LUMINANCE)
    W = weight_tri.sum()
    if not (W > 0):
        return None
    corners = g.positions[tri]  # (e, 3, 3)
    n_tri = g.face_normals()[tri]
    # Cull points that see none of the emitters' bounding box above their surface.
    lo, hi = corners.reshape(-1, 3).min(0), corners.reshape(-1, 3).max(0)
    box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    to_box = box[None] - p[:, None, :]
    can = np.any(_dot(n_g[:, None, :], to_box) > 0, axis=1) & np.any(_dot(n_s[:, None, :], to_box) > 0, axis=1)
    idx = np.flatnonzero(can)
    pk, nsk, ngk = (np.take(v, idx, axis=0) for v in (p, n_s, n_g))

    # Pick a triangle with u0 through the CDF, reuse the remainder of u0 for the position.
    pmf = weight_tri / W
    cdf = np.cumsum(pmf)
    cdf[-1] = 1.0
    u = sampling.stratified_2d(len(idx), samples, rng)
    k = np.minimum(np.searchsorted(cdf, u[..., 0], side="right"), len(tri) - 1)
    start = cdf[k] - pmf[k]
    u0 = np.clip(np.divide(u[..., 0] - start, pmf[k], out=np.zeros_like(start), where=pmf[k] > 0), 0.0,
                 np.nextafter(1.0, 0.0))
    bary, _ = sampling.uniform_triangle(np.stack([u0, u[..., 1]], axis=-1))
    tc = corners[k]  # (k, m, 3, 3)
    q = (1.0 - bary[..., 0:1] - bary[..., 1:2]) * tc[..., 0, :] + bary[..., 0:1] * tc[..., 1, :] \
        + bary[..., 1:2] * tc[..., 2, :]
    w = q - pk[:, None, :]
    d = norms(w)
    w = np.divide(w, d[..., None], out=np.zeros_like(w), where=d[..., None] > 0)
    cos_s = _dot(nsk[:, None, :], w)
    facing = -_dot(n_tri[k], w)
    cos_l = np.abs(facing)  # two-sided emission
    ok = (d > 0) & (cos_s > 0) & (cos_l > 0) & (_dot(ngk[:, None, :], w) > 0)
    # pdf_area = pmf_k / A_k; estimator Le_k cos_s cos_l / d^2 / pdf_area (per channel).
    pdf_area = np.divide(pmf[k], area[k], out=np.zeros_like(d), where=area[k] > 0)
    geom = np.divide(cos_s * cos_l, d * d * pdf_area, out=np.zeros_like(d), where=ok & (pdf_area > 0))
    ok &= geom > 0
    m_toward = np.sign(facing)[..., None] * n_tri[k]  # the emitting side, toward the receiver
    return ShadowSamples("emissive", EMISSIVE_KEY, idx, _lift_off_emitter(q, m_toward, caster), geom, ok, Le[k],
                         samples)
