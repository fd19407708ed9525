"""Blender lights and world -> :mod:`core.scene` lights and :class:`core.scene.World`.

Unit conversions (DEVELOPERS.md, "Units"); all in world coordinates here, the
caller recentres positions with the scene's origin:

=========  ======================================================================
point      power = energy * 2**exposure * colour (W); radius = shadow_soft_size;
           ``use_soft_falloff`` off: a uniform sphere (``soft_falloff=False``)
spot       as point; direction = -Z of matrix_world; half_angle = spot_size / 2;
           blend = spot_blend
sun        irradiance = strength * 2**exposure * colour (W/m^2); direction =
           +Z of matrix_world (towards the sun); half_angle = angle / 2
area       size (and size_y for RECTANGLE/ELLIPSE) times the object's scale
           along its X and Y axes; normal = -Z (it emits down its -Z axis);
           radiance = power / (pi * area) (W/m^2/sr), one-sided; with Cycles'
           *Portal* on, no light (a portal emits nothing in Cycles: :func:`is_portal`)
world      Background node into the World Output: radiance = Color * Strength
=========  ======================================================================

``Light.normalize`` off (measured against Cycles 5.0 bakes, tests/test_direct_vs_cycles.py):
Cycles no longer divides the power by the emitter's size, so

===========  ====================================================================
point, spot  radius r > 0: power x 4 pi r^2 (radiance P / pi); radius 0: power x 4
sun          angle a > 0: strength x pi sin^2(a / 2) (radiance = strength);
             angle 0: unchanged
area         radiance = P / pi (the area is taken as 1 m^2)
===========  ====================================================================

``colour`` includes the blackbody ``temperature_color`` when ``use_temperature``.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..core.scene import AreaLight, PointLight, SceneError, SpotLight, SunLight, World
from .extract_materials import USE_NODES_FLAG, _linked_node, _output_node


def normalize_factor(light) -> float:
    """Power multiplier of a point, spot or sun light with ``normalize`` off (1 when on).

    Measured against Cycles 5.0 (Diffuse Direct bakes, normalize off / on):
    point and spot radius r > 0: 4 pi r^2 (r = 0.1, 0.25, 0.5, 1 m); radius 0: 4;
    sun with angle a > 0: pi sin^2(a / 2) (a = 0.1, 0.3 rad); sun with angle 0: 1.
    Area lights are handled where their radiance is set.
    """
    if getattr(light, "normalize", True):
        return 1.0
    if light.type in ("POINT", "SPOT"):
        r = float(light.shadow_soft_size)
        return 4.0 * math.pi * r * r if r > 0 else 4.0
    if light.type == "SUN":
        half = 0.5 * float(light.angle)
        return math.pi * math.sin(half) ** 2 if half > 0 else 1.0
    return 1.0


def _unit(v: np.ndarray, what: str) -> np.ndarray:
    n = float(np.linalg.norm(v))
    if not (n > 0 and math.isfinite(n)):
        raise SceneError(f"{what}: degenerate transform (zero or non-finite axis)")
    return v / n


def light_power(light) -> np.ndarray:
    """(3,) float64 Blender power (W) or sun strength (W/m^2): energy * 2**exposure * colour.

    Parameters
    ----------
    light : bpy.types.Light (evaluated or original).
    """
    color = np.array(light.color[:3], np.float64)
    if getattr(light, "use_temperature", False):
        color = color * np.array(light.temperature_color[:3], np.float64)
    return float(light.energy) * 2.0 ** float(getattr(light, "exposure", 0.0)) * color


def _point(light, M: np.ndarray, name: str, power: np.ndarray, warnings: list) -> PointLight:
    """A POINT light: position, power, soft radius (a uniform sphere when Soft Falloff is off)."""
    return PointLight(name=name, position=M[:3, 3].copy(), power=power, radius=float(light.shadow_soft_size),
                      soft_falloff=_soft_falloff(light))


def _spot(light, M: np.ndarray, name: str, power: np.ndarray, warnings: list) -> SpotLight:
    """A SPOT light: a point light masked by its cone, pointing down the object's -Z."""
    return SpotLight(
        name=name,
        position=M[:3, 3].copy(),
        direction=_unit(-M[:3, 2], f"light {name!r}"),
        power=power,
        half_angle=0.5 * float(light.spot_size),
        blend=float(light.spot_blend),
        radius=float(light.shadow_soft_size),
        soft_falloff=_soft_falloff(light),
    )


def _sun(light, M: np.ndarray, name: str, power: np.ndarray, warnings: list) -> SunLight:
    """A SUN light: strength as irradiance, from the object's +Z, angular diameter ``angle``."""
    return SunLight(name=name, direction=_unit(M[:3, 2], f"light {name!r}"), irradiance=power,
                    half_angle=0.5 * float(light.angle))


def _area(light, M: np.ndarray, name: str, power: np.ndarray, warnings: list) -> AreaLight | None:
    """An AREA light: sizes times the object's X/Y scale, emitting down -Z, radiance P / (pi A)."""
    scale_u = float(np.linalg.norm(M[:3, 0]))
    scale_v = float(np.linalg.norm(M[:3, 1]))
    size_u = float(light.size) * scale_u
    size_v = float(light.size_y if light.shape in ("RECTANGLE", "ELLIPSE") else light.size) * scale_v
    if getattr(light, "spread", math.pi) < math.pi - 1e-6:
        warnings.append(f"light {name!r}: area light spread below 180 degrees is ignored (emits as a full Lambertian)")
    area = AreaLight(
        name=name,
        position=M[:3, 3].copy(),
        normal=_unit(-M[:3, 2], f"light {name!r}"),
        axis_u=_unit(M[:3, 0], f"light {name!r}"),
        axis_v=_unit(M[:3, 1], f"light {name!r}"),
        size_u=size_u,
        size_v=size_v,
        shape=light.shape,
        radiance=np.zeros(3),
    )
    if area.area <= 0:
        warnings.append(f"light {name!r}: area light of zero size ignored")
        return None
    # Light.normalize (default True): power is spread over the area, L = P / (pi A);
    # off: L = P / pi, whatever the size (measured: Cycles 5.0, sizes 0.5, 1, 2 m).
    divisor = area.area if getattr(light, "normalize", True) else 1.0
    return replace(area, radiance=power / (math.pi * divisor))


def _soft_falloff(light) -> bool:
    """False when a point/spot of radius > 0 has Soft Falloff off (a uniform sphere)."""
    return bool(getattr(light, "use_soft_falloff", True)) or float(light.shadow_soft_size) <= 0


LIGHT_BUILDERS = {"POINT": _point, "SPOT": _spot, "SUN": _sun, "AREA": _area}
"""Blender light type -> builder(light, matrix_world (4, 4), name, power (3,), warnings) -> core light or None."""


def extract_light(light, matrix_world: np.ndarray, name: str, warnings: list):
    """One Blender light as a core light, in world coordinates.

    Parameters
    ----------
    light : bpy.types.Light, the light object's data.
    matrix_world : (4, 4) float64 object-to-world transform (of the instance, for instanced lights).
    name : name for messages (object name, ``instancer/object`` for instances).
    warnings : list the messages about approximations are appended to.

    Returns
    -------
    PointLight | SpotLight | SunLight | AreaLight, or None for an unsupported type. A light portal
    (:func:`is_portal`) is no light: the extraction reads it with :func:`extract_portal` instead.
    """
    build = LIGHT_BUILDERS.get(light.type)
    if build is None:
        warnings.append(f"light {name!r}: unsupported light type {light.type!r} ignored")
        return None
    power = light_power(light)
    if np.any(power < 0):
        warnings.append(f"light {name!r}: negative power/strength clamped to 0")
        power = np.maximum(power, 0.0)
    return build(light, np.asarray(matrix_world, np.float64), name, power * normalize_factor(light), warnings)


def extract_portal(light, matrix_world: np.ndarray, name: str, warnings: list) -> AreaLight | None:
    """A light portal (:func:`is_portal`) as the :class:`AreaLight` shape the sun's and the world's photons are
    sent through (``Scene.portals``; deviation portal-photons), in world coordinates; None if it has no area."""
    portal = _area(light, np.asarray(matrix_world, np.float64), name, np.zeros(3), [])
    if portal is None:
        warnings.append(f"light portal {name!r} has no area: ignored")
    return portal


def is_portal(light) -> bool:
    """Whether ``light`` is a Cycles light portal (an area light with *Portal* on): it only guides Cycles'
    sampling of the world through a window and emits nothing (a Cycles 5.0 Diffuse Direct bake with a
    500 W portal over a floor equals the bake without it, tests/test_extract.py): no light here, a window
    for the photons (:func:`extract_portal`)."""
    # The original ID's setting: a script that turns Portal on or off does not tag the depsgraph (Cycles'
    # property group), so an evaluated copy may still hold the old value.
    settings = getattr(getattr(light, "original", light), "cycles", None)
    return light.type == "AREA" and bool(getattr(settings, "is_portal", False))


def recentre_light(light, origin_world: np.ndarray):
    """``light`` with its position moved to scene-local coordinates (a sun has none)."""
    if not hasattr(light, "position"):
        return light
    return replace(light, position=light.position - origin_world)


def extract_world(world, warnings: list) -> World:
    """The uniform world radiance (3,) W/m^2/sr of ``world`` (a bpy World or None -> black).

    A Background (or Emission) node linked to the Cycles World Output gives
    Color x Strength; anything linked into Color (an environment or sky texture)
    is replaced by the socket's constant colour with a warning naming the world.
    """
    if world is None:
        return World(radiance=np.zeros(3, np.float32))
    tree = world.node_tree
    if tree is None or (USE_NODES_FLAG and not world.use_nodes):
        return World(radiance=np.array(world.color[:3], np.float32))
    out = _output_node(tree, "OUTPUT_WORLD")
    fed = None if out is None else _linked_node(out.inputs["Surface"])
    if fed is None:
        return World(radiance=np.zeros(3, np.float32))
    node = fed[0]
    if node.type not in ("BACKGROUND", "EMISSION"):
        warnings.append(f"world {world.name!r}: unsupported node {node.name!r} ({node.bl_idname}) on the World Output; world is black")
        return World(radiance=np.zeros(3, np.float32))
    color_socket, strength_socket = node.inputs["Color"], node.inputs["Strength"]
    for socket in (color_socket, strength_socket):
        fed_socket = _linked_node(socket)
        if fed_socket is not None:
            warnings.append(
                f"world {world.name!r}: {socket.name} is driven by node {fed_socket[0].name!r} ({fed_socket[0].bl_idname}) "
                "(not supported); using the socket's constant value"
            )
    radiance = np.array(color_socket.default_value[:3], np.float64) * float(strength_socket.default_value)
    return World(radiance=np.maximum(radiance, 0.0).astype(np.float32))
