"""The scene as the core sees it: plain, typed, validated numpy arrays.

Everything here is bpy-free. ``pdic_addon.extract`` builds a :class:`Scene`
from Blender's evaluated depsgraph; tests and benchmarks build them directly.

Coordinates are *scene-local*: world positions minus :attr:`Scene.origin_world`
(the centre of the bounding box, kept in float64). Working relative to the
centre is what keeps a scene placed 1e5 units from the world origin as
accurate as one at the origin once positions are cast to float32 for Embree.

Units follow Blender (see DEVELOPERS.md): lengths in scene units, light power
in watts, sun strength as irradiance (W/m^2), emission and world strength as
radiance (W/m^2/sr).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .lights import AreaLight, EmissiveMesh, Light, PointLight, SceneError, SpotLight, SunLight, World
from .vectors import unit

__all__ = ["AreaLight", "BakeTarget", "EmissiveMesh", "Geometry", "Light", "Materials", "PointLight", "Scene",
           "SceneError", "SpotLight", "SunLight", "Texture", "World", "recentre", "unit_face_normals"]


def _require(array: np.ndarray, name: str, dtype, shape_tail: tuple) -> np.ndarray:
    """Return ``array`` as a C-contiguous ``dtype`` array, checking its trailing shape."""
    out = np.ascontiguousarray(array, dtype=dtype)
    if out.shape[1:] != shape_tail and not (shape_tail == () and out.ndim == 1):
        raise SceneError(f"{name}: expected shape (n, {', '.join(map(str, shape_tail))}), got {out.shape}")
    return out


# --------------------------------------------------------------------------- geometry
def unit_face_normals(positions: np.ndarray) -> np.ndarray:
    """(T, 3) float64 unit normals of (T, 3, 3) triangles (right-handed winding); zero for degenerate ones."""
    p = np.asarray(positions, dtype=np.float64)
    if len(p) == 0:
        return np.zeros((0, 3))
    return unit(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]))


@dataclass(frozen=True)
class Geometry:
    """All triangles of the scene, baked or not (struct of arrays, T triangles).

    Memory: 72 + 36 + 24 + 4 + 4 + 4 = 144 bytes per triangle.

    Attributes
    ----------
    positions : (T, 3, 3) float64, scene-local corner positions.
    normals : (T, 3, 3) float32, unit shading normals per corner (smooth or flat,
        as Blender's corner normals); they point to the side Cycles bakes.
    uvs : (T, 3, 2) float32, the material's texture coordinates per corner
        (zeros where the mesh has no UV map).
    material : (T,) int32, index into :class:`Materials`.
    target : (T,) int32, index into :attr:`Scene.targets` of the bake target the
        triangle belongs to, or -1 for occluder-only geometry (instances, objects
        not selected for baking).
    transmission : (T,) float32 in [0, 1], the probability that a shadow ray or a
        photon passes straight through the triangle (Cycles' transparent shadows:
        1 - Alpha, Principled Transmission, ray visibility Shadow off); None -> 0,
        every triangle opaque.
    """

    positions: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    material: np.ndarray
    target: np.ndarray
    transmission: np.ndarray | None = None

    def __post_init__(self):
        object.__setattr__(self, "positions", _require(self.positions, "positions", np.float64, (3, 3)))
        object.__setattr__(self, "normals", _require(self.normals, "normals", np.float32, (3, 3)))
        object.__setattr__(self, "uvs", _require(self.uvs, "uvs", np.float32, (3, 2)))
        object.__setattr__(self, "material", _require(self.material, "material", np.int32, ()))
        object.__setattr__(self, "target", _require(self.target, "target", np.int32, ()))
        tau = np.zeros(len(self.positions), np.float32) if self.transmission is None else self.transmission
        tau = _require(tau, "transmission", np.float32, ())
        if not np.isfinite(tau).all() or tau.min(initial=0.0) < 0 or tau.max(initial=0.0) > 1:
            raise SceneError("geometry.transmission must lie in [0, 1]")
        object.__setattr__(self, "transmission", tau)
        n = len(self.positions)
        for name in ("normals", "uvs", "material", "target", "transmission"):
            if len(getattr(self, name)) != n:
                raise SceneError(f"geometry.{name} has {len(getattr(self, name))} rows, positions has {n}")
        if not np.isfinite(self.positions).all():
            raise SceneError("geometry has non-finite vertex positions")

    @property
    def count(self) -> int:
        return len(self.positions)

    def face_normals(self) -> np.ndarray:
        """(T, 3) float64 unit geometric normals (right-handed winding); zero for degenerate triangles.
        Computed once (read-only), as :meth:`areas`."""
        return self._derived("face_normals", lambda: unit_face_normals(self.positions))

    def areas(self) -> np.ndarray:
        """(T,) float64 triangle areas in scene units squared, computed once (read-only): the texels' stage asks
        per target and the emissive triangles' light per batch of points, each over the whole geometry (300
        targets of 48^2 over Sponza's 66k triangles: their texels lifted in 5.7 s, 2.4 s with it computed once)."""
        p = self.positions
        return self._derived("areas", lambda: 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]),
                                                                    axis=1))

    def _derived(self, name: str, compute) -> np.ndarray:
        """``compute()`` the first time ``name`` is asked, read-only (a caller cannot change what the others
        read); the arrays are frozen, so their functions never change. Two threads may both compute it once."""
        cache = self.__dict__.setdefault("_derived_arrays", {})
        value = cache.get(name)
        if value is None:
            value = compute()
            value.setflags(write=False)
            cache[name] = value
        return value

    def __getstate__(self) -> dict:  # pickled (a Dask worker's copy) without what it can compute again
        return {k: v for k, v in self.__dict__.items() if k != "_derived_arrays"}


# --------------------------------------------------------------------------- materials
@dataclass(frozen=True)
class Texture:
    """A base-colour image in linear RGB, sampled with repeat wrapping.

    pixels : (H, W, 3) float32, linear (sRGB images are decoded at extraction);
        row 0 is the *bottom* of the image, as in Blender's ``Image.pixels``.
    """

    name: str
    pixels: np.ndarray
    interpolation: str = "Linear"  # "Linear" or "Closest", as Blender's Image Texture node

    def __post_init__(self):
        px = np.ascontiguousarray(self.pixels, dtype=np.float32)
        if px.ndim != 3 or px.shape[2] != 3 or px.shape[0] < 1 or px.shape[1] < 1:
            raise SceneError(f"texture {self.name!r}: expected (H, W, 3) pixels, got {px.shape}")
        object.__setattr__(self, "pixels", np.nan_to_num(px, nan=0.0, posinf=0.0, neginf=0.0))


@dataclass(frozen=True)
class Materials:
    """Diffuse materials (struct of arrays, M materials).

    names : M material names (for messages).
    base_color : (M, 3) float32 linear albedo in [0, 1] (Principled Base Color).
    texture : (M,) int32 index into :attr:`Scene.textures`, or -1 for a constant
        base colour. A texture replaces ``base_color``.
    emission : (M, 3) float32 emitted radiance, W/m^2/sr (Emission Color x Strength).
    """

    names: tuple
    base_color: np.ndarray
    texture: np.ndarray
    emission: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "base_color", np.clip(_require(self.base_color, "base_color", np.float32, (3,)), 0.0, 1.0))
        object.__setattr__(self, "texture", _require(self.texture, "texture", np.int32, ()))
        emission = _require(self.emission, "emission", np.float32, (3,))
        object.__setattr__(self, "emission", np.maximum(emission, 0.0))
        m = len(self.names)
        if not (len(self.base_color) == len(self.texture) == len(self.emission) == m):
            raise SceneError("materials: names, base_color, texture and emission differ in length")
        if not (np.isfinite(self.base_color).all() and np.isfinite(self.emission).all()):
            raise SceneError("materials: non-finite base colour or emission")

    @staticmethod
    def default(count: int = 1) -> "Materials":
        """``count`` grey (0.8) non-emissive materials: Blender's default surface."""
        return Materials(
            names=tuple(f"default{i}" for i in range(count)),
            base_color=np.full((count, 3), 0.8, np.float32),
            texture=np.full(count, -1, np.int32),
            emission=np.zeros((count, 3), np.float32),
        )

    @property
    def count(self) -> int:
        return len(self.names)


# --------------------------------------------------------------------------- lights
# The light types and the world live in core/lights.py (one interface: flux, emit,
# sample_toward); they are re-exported here, where the extraction builds them.


# --------------------------------------------------------------------------- bake targets
@dataclass(frozen=True)
class BakeTarget:
    """One object that receives a light map.

    name : object name (for messages, file names and the manifest).
    triangles : (t,) int64 indices into :class:`Geometry` of this object's triangles.
    lightmap_uv : (t, 3, 2) float32 light-map UVs per corner, in [0, 1].
    width, height : light-map resolution in texels.
    """

    name: str
    triangles: np.ndarray
    lightmap_uv: np.ndarray
    width: int
    height: int

    def __post_init__(self):
        object.__setattr__(self, "triangles", np.ascontiguousarray(self.triangles, dtype=np.int64))
        uv = _require(self.lightmap_uv, f"{self.name}: lightmap_uv", np.float32, (3, 2))
        object.__setattr__(self, "lightmap_uv", uv)
        if len(uv) != len(self.triangles):
            raise SceneError(f"{self.name}: {len(uv)} light-map UV triangles for {len(self.triangles)} triangles")
        if self.width < 1 or self.height < 1:
            raise SceneError(f"{self.name}: light-map resolution {self.width}x{self.height} is empty")


# --------------------------------------------------------------------------- scene
_EMITTERS = "_emitters"
"""Where a :class:`Scene` keeps its :meth:`~Scene.emitters` once made (not a field: no part of its equality)."""


@dataclass(frozen=True)
class Scene:
    """Everything a bake needs, in scene-local coordinates."""

    geometry: Geometry
    materials: Materials
    textures: tuple = ()
    lights: tuple = ()
    world: World = field(default_factory=World)
    targets: tuple = ()
    origin_world: np.ndarray = field(default_factory=lambda: np.zeros(3))
    portals: tuple = ()
    """Light portals (:class:`AreaLight` shapes; their radiance is not read): windows a sun's and the world's
    photons are sent through (deviation: portal-photons, core/portals.py). They emit nothing."""

    def __post_init__(self):
        object.__setattr__(self, "textures", tuple(self.textures))
        object.__setattr__(self, "lights", tuple(self.lights))
        object.__setattr__(self, "portals", tuple(self.portals))
        object.__setattr__(self, "targets", tuple(self.targets))
        g, m = self.geometry, self.materials
        if g.count and (g.material.min() < 0 or g.material.max() >= m.count):
            raise SceneError("geometry refers to a material index out of range")
        bad = m.texture[(m.texture >= len(self.textures))]
        if len(bad):
            raise SceneError("a material refers to a texture index out of range")

    @property
    def extent(self) -> float:
        """Diagonal of the bounding box in scene units (at least 1e-12); sets ray offsets and radii."""
        if self.geometry.count == 0:
            return 1.0
        p = self.geometry.positions.reshape(-1, 3)
        return float(max(np.linalg.norm(p.max(0) - p.min(0)), 1e-12))

    @property
    def emissive_triangles(self) -> np.ndarray:
        """(e,) int64 indices of triangles whose material emits."""
        emits = np.any(self.materials.emission > 0, axis=1)
        return np.flatnonzero(emits[self.geometry.material])

    def emitters(self) -> tuple:
        """Every emitter behind the light interface (core/lights.py), in a fixed order: the lights,
        then the emissive triangles (if any), then the world (unless black).

        Made once per scene (a scene is immutable; :func:`dataclasses.replace` makes a new one): every
        batch of shadow rays asks, and finding the emissive triangles reads every triangle's material."""
        cached = self.__dict__.get(_EMITTERS)
        if cached is not None:
            return cached
        out = list(self.lights)
        triangles = self.emissive_triangles
        if len(triangles):
            out.append(EmissiveMesh(self.geometry, self.materials, triangles))
        if not self.world.is_black:
            out.append(self.world)
        cached = self.__dict__.setdefault(_EMITTERS, tuple(out))  # two threads at once: both get the first
        return cached

    def __getstate__(self) -> dict:
        """A pickled scene (a Dask worker's, the bench's) leaves its emitters behind: they are made again."""
        return {k: v for k, v in self.__dict__.items() if k != _EMITTERS}

    def has_light(self) -> bool:
        """True if anything in the scene emits: a light with power, an emissive triangle or the world."""
        return any(emitter.emits() for emitter in self.emitters())


def recentre(positions_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split world positions (..., 3) float64 into (scene-local positions, origin_world).

    The origin is the bounding-box centre, so float32 ray tracing keeps full
    relative precision however far the scene sits from the world origin.
    """
    p = np.asarray(positions_world, dtype=np.float64)
    flat = p.reshape(-1, 3)
    if len(flat) == 0:
        return p.copy(), np.zeros(3)
    origin = 0.5 * (flat.min(0) + flat.max(0))
    return p - origin, origin
