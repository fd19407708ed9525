"""Hand-built core scenes with closed-form answers, shared by the core tests (no bpy)."""
from __future__ import annotations

import numpy as np

from pdic.core.scene import BakeTarget, Geometry, Materials, PointLight, Scene, World, recentre


def icosphere(subdivisions: int = 3, radius: float = 1.0, inward: bool = True) -> np.ndarray:
    """(T, 3, 3) triangles of an icosphere; normals point inward when ``inward``."""
    t = (1 + 5 ** 0.5) / 2
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float)
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6],
         [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10],
         [8, 6, 7], [9, 8, 1]]
    tris = v[np.array(f)]
    tris /= np.linalg.norm(tris, axis=2, keepdims=True)
    for _ in range(subdivisions):
        a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
        ab, bc, ca = [(x / np.linalg.norm(x, axis=1, keepdims=True)) for x in (a + b, b + c, c + a)]
        tris = np.concatenate([np.stack(s, 1) for s in ([a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca])])
    tris = tris * radius
    if inward:
        tris = tris[:, [0, 2, 1]]
    return tris


def geometry(tris: np.ndarray, material: np.ndarray | None = None, target: np.ndarray | None = None) -> Geometry:
    tris = np.asarray(tris, float)
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    T = len(tris)
    return Geometry(tris, np.repeat(n[:, None], 3, axis=1), np.zeros((T, 3, 2)),
                    np.zeros(T, np.int32) if material is None else material,
                    np.full(T, -1, np.int32) if target is None else target)


def quad(corner, edge_u, edge_v) -> np.ndarray:
    """Two triangles (2, 3, 3) spanning corner + s edge_u + t edge_v; normal edge_u x edge_v."""
    c, u, v = (np.asarray(x, float) for x in (corner, edge_u, edge_v))
    return np.array([[c, c + u, c + u + v], [c, c + u + v, c + v]])


def quad_points(corner, edge_u, edge_v, k: int) -> np.ndarray:
    """(k^2, 3) the centres of a k x k grid over corner + s edge_u + t edge_v (s along the rows)."""
    g = (np.arange(k) + 0.5) / k
    u, v = (a.ravel()[:, None] for a in np.meshgrid(g, g))
    return np.asarray(corner, float) + u * np.asarray(edge_u, float) + v * np.asarray(edge_v, float)


def plane_target(name: str, first_triangle: int, resolution: int) -> BakeTarget:
    """A bake target for a quad made by :func:`quad` (UVs = the quad's own s, t)."""
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
    return BakeTarget(name, np.array([first_triangle, first_triangle + 1]), uv, resolution, resolution)


def furnace(albedo: float, radiance: float, subdivisions: int = 3) -> Scene:
    """Inside of a sphere whose every triangle emits ``radiance`` and reflects ``albedo``."""
    tris = icosphere(subdivisions)
    mats = Materials(("wall",), np.full((1, 3), albedo), np.array([-1]), np.full((1, 3), radiance))
    local, origin = recentre(tris)
    return Scene(geometry(local), mats, origin_world=origin)


UV_QUAD = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
"""Light-map UVs of a quad made by :func:`quad` (its own s, t)."""


def box_faces() -> list:
    """The inside of the unit box [0, 1]^3: floor, back, ceiling, front, left, right (normals inward)."""
    return [quad([0, 0, 0], [1, 0, 0], [0, 1, 0]), quad([0, 1, 0], [1, 0, 0], [0, 0, 1]),
            quad([0, 0, 1], [0, 1, 0], [1, 0, 0]), quad([0, 0, 0], [0, 0, 1], [1, 0, 0]),
            quad([0, 0, 0], [0, 1, 0], [0, 0, 1]), quad([1, 0, 0], [0, 0, 1], [0, 1, 0])]


def closed_box(lo, hi) -> list:
    """The six faces of the axis-aligned box [lo, hi] as quads, normals outward: bottom, top, front (-y),
    back (+y), left (-x), right (+x)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    X, Y, Z = x1 - x0, y1 - y0, z1 - z0
    return [quad([x0, y0, z0], [0, Y, 0], [X, 0, 0]), quad([x0, y0, z1], [X, 0, 0], [0, Y, 0]),
            quad([x0, y0, z0], [X, 0, 0], [0, 0, Z]), quad([x0, y1, z0], [0, 0, Z], [X, 0, 0]),
            quad([x0, y0, z0], [0, 0, Z], [0, Y, 0]), quad([x1, y0, z0], [0, Y, 0], [0, 0, Z])]


BOX_LAMP = PointLight("lamp", np.array([0.5, 0.5, 0.8]), np.full(3, 100.0))
"""A 100 W point light under the ceiling of :func:`box_faces`' unit box (world space)."""


def lamp_box(resolution: int) -> Scene:
    """The unit box lit by BOX_LAMP, its floor and back wall the bake targets at ``resolution``^2."""
    return quad_scene(box_faces(), {"floor": (0, resolution), "back": (1, resolution)}, [BOX_LAMP])


def seed_difference(a: dict, b: dict) -> float:
    """Two bakes' maps by target name (e.g. ``result.indirect`` of two seeds): the mean over targets of
    their RMS difference relative to the first's mean."""
    return float(np.mean([np.sqrt(np.mean((a[k] - b[k]) ** 2)) / a[k].mean() for k in a]))


def quad_scene(faces, targets: dict, lights, albedo: float = 0.7, emission=None, materials=None,
               extra=None) -> Scene:
    """A scene of quads in world space (recentred), some of them bake targets.

    faces : quads, each (2, 3, 3) from :func:`quad`. targets : {name: (quad index, resolution)}.
    lights : lights with world positions (moved into scene-local space here).
    albedo : base colour of every material. emission, materials : (M, 3) radiance per material
    and (T,) material index per triangle (default: one grey material).
    extra : optional (k, 3, 3) occluder-only triangles appended after the quads.
    """
    from dataclasses import replace

    tris = np.concatenate(faces)
    if extra is not None:
        tris = np.concatenate([tris, np.asarray(extra, float)])
    local, origin = recentre(tris)
    target = np.full(len(tris), -1, np.int32)
    bake_targets = []
    for i, (name, (face, res)) in enumerate(targets.items()):
        target[2 * face:2 * face + 2] = i
        bake_targets.append(BakeTarget(name, np.array([2 * face, 2 * face + 1]), UV_QUAD, res, res))
    material = np.zeros(len(tris), np.int32) if materials is None else materials
    M = int(material.max()) + 1
    mats = Materials(tuple(f"m{i}" for i in range(M)), np.full((M, 3), albedo), np.full(M, -1),
                     np.zeros((M, 3)) if emission is None else emission)
    moved = tuple(replace(light, position=np.asarray(light.position, float) - origin) for light in lights)
    return Scene(geometry(local, material, target), mats, lights=moved, targets=tuple(bake_targets),
                 origin_world=origin)


def lit(tris: np.ndarray, *lights, world=None) -> Scene:
    """Triangles (T, 3, 3) in scene-local space, one grey default material, the given lights/world."""
    return Scene(geometry(tris), Materials.default(1), lights=lights, world=world or World())


def box_on_ground(res: int = 16):
    """A 4 x 4 m ground plane (one face, up), a closed unit box standing on it (its bottom face down, in
    the ground's plane) and a 1 x 1 m upright sheet of two faces back to back (split along different
    diagonals: not copies of each other), under a white sky."""
    from dataclasses import replace

    X, Y, Z = np.eye(3)
    faces = [quad(np.array([-2.0, -2.0, 0.0]), 4 * X, 4 * Y),  # 0 ground
             quad(np.zeros(3), Y, X), quad(Z, X, Y), quad(np.zeros(3), X, Z), quad(Y, Z, X),  # 1 bottom, top, front, back
             quad(np.zeros(3), Z, Y), quad(X, Y, Z),  # left, right
             quad(np.array([-1.5, 1.5, 0.0]), X, Z), quad(np.array([-0.5, 1.5, 0.0]), -X, Z)]  # 7, 8 the sheet
    targets = {"ground": (0, res), "bottom": (1, res), "top": (2, res), "sheet_front": (7, res), "sheet_back": (8, res)}
    return replace(quad_scene(faces, targets, []), world=World(np.full(3, 1.0)))


def bake_samples(scene: Scene, texel_samples: int = 2):
    """The texel samples (:class:`core.texels.TexelPoints`) a bake at default deviations places in ``scene``:
    ``texel_samples``^2 per texel, more where an edge between triangles or a chart's edge crosses a texel
    (folded onto the centre triangle, docs/DEVIATIONS.md crease-folding and edge-folding)."""
    from pdic.core import texels

    points, _ = texels.lift_texels(scene, texel_samples, crease_folding=True, edge_folding=True)
    return points
