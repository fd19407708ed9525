"""The light-map UV map: read a mesh's triangles out, write PDIC_Lightmap back.

Data leaves Blender through ``foreach_get`` into typed arrays and comes back
through ``foreach_set``. Adding or removing the light-map UV map never changes
which UV map is active or renders (the user's texture mapping stays as it is),
except on a mesh that had no UV map at all, where Blender makes the first map
active and rendering.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LIGHTMAP_UV = "PDIC_Lightmap"
MAX_UV_MAPS = 8  # Blender's limit per mesh


class UVMapError(ValueError):
    """A mesh cannot take a light-map UV map; the message names it."""


@dataclass(frozen=True)
class MeshTriangles:
    """A mesh's loop triangles as typed arrays (object space).

    positions : (V, 3) float64 vertex positions, object space.
    triangles : (t, 3) int64 vertex indices.
    loops : (t, 3) int64 loop (polygon corner) indices.
    polygon : (t,) int64 polygon of each triangle.
    loop_count : number of loops of the mesh.
    """

    positions: np.ndarray
    triangles: np.ndarray
    loops: np.ndarray
    polygon: np.ndarray
    loop_count: int

    def triangle_areas(self, scale=(1.0, 1.0, 1.0)) -> np.ndarray:
        """(t,) area of each triangle, scene units squared, after scaling positions by ``scale`` (3,)."""
        p = self.positions * np.asarray(scale, dtype=np.float64)
        c = p[self.triangles]
        return 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)

    def surface_area(self, scale=(1.0, 1.0, 1.0)) -> float:
        """Total area, scene units squared, after scaling positions by ``scale`` (3,)."""
        return float(self.triangle_areas(scale).sum())


def mesh_triangles(mesh) -> MeshTriangles:
    """Read ``mesh`` (an original ``bpy.types.Mesh``) into :class:`MeshTriangles`."""
    mesh.calc_loop_triangles()
    v, t = len(mesh.vertices), len(mesh.loop_triangles)
    positions = np.empty(v * 3, np.float32)
    mesh.vertices.foreach_get("co", positions)
    triangles = np.empty(t * 3, np.int32)
    mesh.loop_triangles.foreach_get("vertices", triangles)
    loops = np.empty(t * 3, np.int32)
    mesh.loop_triangles.foreach_get("loops", loops)
    polygon = np.empty(t, np.int32)
    mesh.loop_triangles.foreach_get("polygon_index", polygon)
    return MeshTriangles(positions.reshape(v, 3).astype(np.float64), triangles.reshape(t, 3).astype(np.int64),
                         loops.reshape(t, 3).astype(np.int64), polygon.astype(np.int64), len(mesh.loops))


@dataclass(frozen=True)
class UVState:
    """Which UV maps a mesh has and which are active (for snapshots and restoring)."""

    names: tuple
    active: str | None
    active_render: str | None


def uv_state(mesh) -> UVState:
    layers = mesh.uv_layers
    active = layers.active.name if layers.active is not None else None
    render = next((l.name for l in layers if l.active_render), None)
    return UVState(tuple(l.name for l in layers), active, render)


def restore_active(mesh, state: UVState) -> None:
    """Make the UV maps ``state`` named active/rendering again (by name)."""
    layers = mesh.uv_layers
    if state.active is not None and state.active in layers:
        layers.active = layers[state.active]
    if state.active_render is not None and state.active_render in layers:
        layers[state.active_render].active_render = True


def read_uv(mesh, name: str = LIGHTMAP_UV) -> np.ndarray:
    """(loop_count, 2) float32 UVs of the map ``name``."""
    out = np.empty(len(mesh.loops) * 2, np.float32)
    mesh.uv_layers[name].uv.foreach_get("vector", out)
    return out.reshape(-1, 2)


def write_lightmap_uv(mesh, uv_loop: np.ndarray, txn) -> None:
    """Write (loop_count, 2) UVs into the mesh's PDIC_Lightmap map, creating it if needed.

    Every change is recorded in ``txn`` (an object with ``add(undo, label)``) so it
    can be undone exactly: a new map is removed again, an existing one gets its
    previous UVs back; active and active-render maps are restored by name.
    """
    uv_loop = np.ascontiguousarray(uv_loop, dtype=np.float32)
    if uv_loop.shape != (len(mesh.loops), 2):
        raise UVMapError(f"mesh {mesh.name!r}: {uv_loop.shape[0]} light-map UVs for {len(mesh.loops)} corners")
    if not np.isfinite(uv_loop).all():
        raise UVMapError(f"mesh {mesh.name!r}: non-finite light-map UVs")
    before = uv_state(mesh)
    mesh_name = mesh.name
    layers = mesh.uv_layers
    if LIGHTMAP_UV in layers:
        previous = read_uv(mesh)

        def undo(mesh=mesh, previous=previous):
            mesh.uv_layers[LIGHTMAP_UV].uv.foreach_set("vector", previous.ravel())
            mesh.update()

        txn.add(undo, f"restore UV map {LIGHTMAP_UV} of mesh {mesh_name}")
    else:
        if len(layers) >= MAX_UV_MAPS:
            raise UVMapError(f"mesh {mesh.name!r} already has {MAX_UV_MAPS} UV maps (Blender's limit); "
                             f"remove one to make room for {LIGHTMAP_UV}")
        layer = layers.new(name=LIGHTMAP_UV, do_init=False)
        if layer is None or layer.name != LIGHTMAP_UV:
            raise UVMapError(f"mesh {mesh.name!r}: could not add UV map {LIGHTMAP_UV}")
        restore_active(mesh, before)
        txn.add(lambda mesh=mesh: remove_lightmap_uv(mesh), f"remove UV map {LIGHTMAP_UV} of mesh {mesh_name}")
    layers[LIGHTMAP_UV].uv.foreach_set("vector", uv_loop.ravel())
    mesh.update()


def remove_lightmap_uv(mesh) -> bool:
    """Remove PDIC_Lightmap from ``mesh`` keeping the other maps' active flags; True if it was there."""
    layers = mesh.uv_layers
    if LIGHTMAP_UV not in layers:
        return False
    state = uv_state(mesh)
    layers.remove(layers[LIGHTMAP_UV])
    restore_active(mesh, state)
    mesh.update()
    return True
