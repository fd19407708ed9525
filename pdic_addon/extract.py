"""Scene extraction: Blender's evaluated depsgraph -> :class:`core.scene.Scene`.

This is the one place where scene data leaves Blender (STYLE.md, principle 1).
:func:`extract_scene` runs five named steps, as glTF-Blender-IO's
``extract_primitives`` does:

1. :func:`choose_targets`: which objects render, which of them get light maps;
2. :func:`walk_render_objects`: every evaluated object and instance Cycles renders;
3. :func:`read_object_triangles`: each one's triangles, through ``to_mesh`` and
   ``foreach_get`` into typed arrays, in world space, float64 (materials are read
   into the :class:`MaterialTable` on the way); lights through ``extract_lights``;
4. :func:`assemble_geometry` and :func:`assemble_targets`: one recentred
   :class:`core.scene.Geometry` and the bake targets;
5. :func:`assemble_scene`: lights recentred with the same origin, world, checks.

What renders is what Cycles renders: objects hidden from render
(``hide_render``), objects in collections hidden from render and excluded
collections are skipped. Collection, vertex/face, particle and geometry-node
instances are extracted as occluders and emitters; only an original object of
``bake_objects`` (its non-instance evaluation) becomes a bake target. Curve,
surface, text and metaball objects are read once, from the mesh their
evaluation carries (Blender lists it as an instance of the object itself).

What shadows are cast (``Geometry.transmission``, Cycles' transparent shadows):
materials give 1 - Alpha x (1 - Transmission Weight) (extract_materials), and an
object whose ray visibility *Shadow* is off is fully transmissive: it casts no
shadow and photons pass through it (it still receives light).

Background-mode caveat: ``Context.evaluated_depsgraph_get()`` is a *viewport*
depsgraph. Objects hidden in the viewport but rendered (eye icon, or
"Disable in Viewports") are not among its instances; they are added here
from their evaluation (eye icon) or, when the depsgraph did not evaluate them
("Disable in Viewports"), from their unmodified mesh with a warning.
Modifiers are evaluated with their viewport settings (levels, visibility).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..core.raster import overlapping
from ..core.scene import BakeTarget, Geometry, Scene, SceneError, recentre
from .extract_lights import extract_light, extract_portal, extract_world, is_portal, recentre_light
from .extract_materials import MaterialTable

GEOMETRY_TYPES = frozenset({"MESH", "CURVE", "SURFACE", "FONT", "META"})
"""Object types converted through ``to_mesh()``; other types (hair curves,
point clouds, volumes, grease pencil) are not extracted."""

CONVERTED_TYPES = GEOMETRY_TYPES - {"MESH"}
"""Types whose evaluated mesh the depsgraph also lists as an instance of the object itself."""

DEGENERATE_RELATIVE_AREA = 1e-12
"""A triangle is degenerate when |e1 x e2| <= this * (longest edge)^2 (zero area or collinear corners)."""

SHARED_LIGHTMAP_UV_FRACTION = 0.01
"""A target is refused when the fraction of its evaluated triangles whose light-map UV triangle
repeats exceeds its own mesh's by more than this: its copies (Array, Mirror, geometry nodes)
would share texels."""


@dataclass
class Extraction:
    """What :func:`extract_scene` returns.

    scene : the core scene, scene-local coordinates.
    warnings : one message per approximation or problem, naming the object/material/image.
    target_objects : object names in :attr:`core.scene.Scene.targets` order.
    degenerate_triangles : object name -> count of zero-area triangles (kept as occluders;
        the rasteriser ignores them). Only objects that have some are listed.
    timings : stage name -> seconds (visibility, geometry, materials, lights, assemble).
    """

    scene: Scene
    warnings: list = field(default_factory=list)
    target_objects: list = field(default_factory=list)
    degenerate_triangles: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)


@dataclass
class _Chunk:
    """The triangles of one evaluated object, world space (t triangles)."""

    name: str
    positions_world: np.ndarray  # (t, 3, 3) float64
    normals: np.ndarray  # (t, 3, 3) float32, unit
    uvs: np.ndarray  # (t, 3, 2) float32
    material: np.ndarray  # (t,) int32, global material rows
    lightmap_uv: np.ndarray | None  # (t, 3, 2) float32 for bake targets
    transmission: np.ndarray = None  # (t,) float32 in [0, 1]


@dataclass
class _Targets:
    """Step 1: the view layer's render-visible objects and the bake targets among them."""

    visible: dict  # session_uid -> original object
    bake: dict  # session_uid -> original mesh object, in bake_objects order


# --------------------------------------------------------------------------- 1. which objects
def render_visible_objects(view_layer) -> dict:
    """Original objects of ``view_layer`` that Cycles renders, as {session_uid: object}.

    An object renders when it is not ``hide_render`` and sits in at least one
    collection reachable from the view layer through collections that are
    neither excluded nor ``hide_render``. Viewport-only hiding does not count.
    """
    visible: dict = {}

    def walk(layer_collection, parent_renders: bool):
        if layer_collection.exclude:
            return
        renders = parent_renders and not layer_collection.collection.hide_render
        if renders:
            for ob in layer_collection.collection.objects:
                if not ob.hide_render:
                    visible[ob.session_uid] = ob
        for child in layer_collection.children:
            walk(child, renders)

    walk(view_layer.layer_collection, True)
    return visible


def choose_targets(view_layer, bake_objects, warnings: list) -> _Targets:
    """Step 1: render-visible objects, and the visible meshes of ``bake_objects`` (warning on the rest).

    Raises SceneError when no bake object is a visible mesh.
    """
    visible = render_visible_objects(view_layer)
    bake: dict = {}
    for ob in bake_objects:
        ob = ob.original
        if ob.type != "MESH":
            warnings.append(f"object {ob.name!r}: not a mesh ({ob.type}); no light map baked")
        elif ob.session_uid not in visible:
            warnings.append(f"object {ob.name!r}: hidden from render; no light map baked")
        else:
            bake[ob.session_uid] = ob
    if not bake:
        names = ", ".join(repr(ob.name) for ob in bake_objects) or "none"
        raise SceneError(f"no bakeable mesh among the bake objects ({names}): select visible mesh objects")
    return _Targets(visible, bake)


# --------------------------------------------------------------------------- 2. what renders
def _instancer_renders_itself(ob) -> bool:
    """False for a vertex/face/particle instancer whose own geometry is hidden in renders."""
    if ob.instance_type in ("VERTS", "FACES") or len(getattr(ob, "particle_systems", ())):
        return bool(ob.show_instancer_for_render)
    return True


def _unevaluated_matrix_world(ob, depsgraph):
    """World matrix of an object the depsgraph did not evaluate (disabled in viewports).

    Its stored ``matrix_world`` may be stale, so it is rebuilt from the local
    transform and the parent chain (object parenting only; constraints, drivers
    and bone/vertex parents are not applied).
    """
    matrix = ob.matrix_basis.copy()
    if ob.parent is not None:
        parent = ob.parent.evaluated_get(depsgraph)
        if parent.as_pointer() == ob.parent.as_pointer():
            parent_world = _unevaluated_matrix_world(ob.parent, depsgraph)
        else:
            parent_world = parent.matrix_world
        matrix = parent_world @ ob.matrix_parent_inverse @ matrix
    return matrix


def _carries_own_mesh(depsgraph) -> set:
    """session_uids of curve/surface/text/metaball objects whose evaluated mesh is listed as their own instance."""
    own = set()
    for inst in depsgraph.object_instances:
        if inst.is_instance and inst.parent is not None and inst.object.type == "MESH" \
                and inst.parent.original.type in CONVERTED_TYPES \
                and inst.object.original.session_uid == inst.parent.original.session_uid:
            own.add(inst.parent.original.session_uid)
    return own


def walk_render_objects(depsgraph, targets: _Targets, visit, warnings: list) -> None:
    """Step 2: call ``visit(obj, matrix_world, name, target_uid)`` for every evaluated object Cycles renders.

    ``obj`` is valid only during the call (depsgraph instances are temporary);
    ``target_uid`` is the session_uid of a bake target, else None.
    """
    visible, bake = targets.visible, targets.bake
    own_mesh = _carries_own_mesh(depsgraph)
    seen: set = set()
    for inst in depsgraph.object_instances:
        obj = inst.object
        orig = obj.original
        if inst.is_instance:
            instancer = inst.parent.original if inst.parent is not None else None
            if orig.hide_render or (instancer is not None and instancer.session_uid not in visible):
                continue
            own = instancer is not None and instancer.session_uid == orig.session_uid
            name = obj.name if own or inst.parent is None else f"{inst.parent.name}/{obj.name}"
            visit(obj, inst.matrix_world, name, None)
            continue
        uid = orig.session_uid
        if uid not in visible:
            continue
        seen.add(uid)
        # A curve's mesh is read from its own instance: reading the curve too doubled its light.
        if _instancer_renders_itself(orig) and uid not in own_mesh:
            visit(obj, inst.matrix_world, obj.name, uid if uid in bake else None)
    _walk_viewport_hidden(depsgraph, targets, seen, visit, warnings)


def _walk_viewport_hidden(depsgraph, targets: _Targets, seen: set, visit, warnings: list) -> None:
    """Objects that render but the viewport depsgraph does not list (hidden in the viewport)."""
    for uid, ob in targets.visible.items():
        if uid in seen or (ob.type not in GEOMETRY_TYPES and ob.type != "LIGHT") or not _instancer_renders_itself(ob):
            continue
        evaluated = ob.evaluated_get(depsgraph)
        if evaluated.as_pointer() == ob.as_pointer():
            warnings.append(
                f"object {ob.name!r}: renders but is disabled in viewports; extracted without its modifiers, "
                "constraints and instances (enable it in viewports for an exact bake)"
            )
            matrix_world = _unevaluated_matrix_world(ob, depsgraph)
        else:
            matrix_world = evaluated.matrix_world
            if ob.is_instancer:
                warnings.append(f"object {ob.name!r}: hidden in the viewport; its instances are not extracted")
        visit(evaluated, matrix_world, ob.name, uid if uid in targets.bake else None)


# --------------------------------------------------------------------------- 3. triangles
def _materials_of(obj, mesh, table: MaterialTable) -> np.ndarray:
    """(slots,) int32 global material rows of an evaluated object's slots (object-linked slots win)."""
    slots = obj.material_slots
    count = max(len(slots), len(mesh.materials))
    rows = []
    for i in range(count):
        slot = slots[i] if i < len(slots) else None
        if slot is not None and slot.link == "OBJECT":
            material = slot.material
        elif i < len(mesh.materials):
            material = mesh.materials[i]
        else:
            material = slot.material if slot is not None else None
        rows.append(table.index(material))
    return np.array(rows or [table.index(None)], np.int32)


def _read_uv(mesh, layer, loops: np.ndarray) -> np.ndarray:
    """(t, 3, 2) float32 corner UVs of ``layer`` gathered at loop indices ``loops`` (3t,)."""
    uv = np.empty(2 * len(mesh.loops), np.float32)
    layer.uv.foreach_get("vector", uv)
    return uv.reshape(-1, 2)[loops].reshape(-1, 3, 2)


@dataclass
class _MeshArrays:
    """Typed copies of one evaluated mesh (t loop triangles, v vertices, l loops)."""

    loops: np.ndarray  # (3t,) int32 loop index per triangle corner
    vertices: np.ndarray  # (3t,) int32 vertex index per triangle corner
    material_local: np.ndarray  # (t,) int32 slot index
    co: np.ndarray  # (v, 3) float64 object-space positions
    corner_normals: np.ndarray  # (t, 3, 3) float64 object-space corner normals


def _mesh_arrays(mesh) -> _MeshArrays:
    """Copy a mesh's triangles out of Blender with ``foreach_get`` into preallocated typed arrays."""
    tris = mesh.loop_triangles
    t = len(tris)
    loops = np.empty(3 * t, np.int32)
    tris.foreach_get("loops", loops)
    vertices = np.empty(3 * t, np.int32)
    tris.foreach_get("vertices", vertices)
    material_local = np.empty(t, np.int32)
    tris.foreach_get("material_index", material_local)
    co = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.vertices.foreach_get("co", co)
    corner_normals = np.empty(3 * len(mesh.loops), np.float32)
    mesh.corner_normals.foreach_get("vector", corner_normals)
    normals = corner_normals.astype(np.float64).reshape(-1, 3)[loops].reshape(t, 3, 3)
    return _MeshArrays(loops, vertices, material_local, co.astype(np.float64).reshape(-1, 3), normals)


def _texture_uvs(mesh, loops: np.ndarray, rows: np.ndarray, table: MaterialTable, name: str) -> np.ndarray:
    """(t, 3, 2) float32 texture UVs: the active render UV map, or the one a material's UV Map node names."""
    render_layer = next((layer for layer in mesh.uv_layers if layer.active_render), None)
    uvs = _read_uv(mesh, render_layer, loops) if render_layer is not None else np.zeros((len(rows), 3, 2), np.float32)
    for row in np.unique(rows):
        wanted = table.uv_map_of(int(row))
        if not wanted or (render_layer is not None and wanted == render_layer.name):
            continue
        layer = mesh.uv_layers.get(wanted)
        if layer is None:
            table.warnings.append(f"object {name!r}: material {table.name_of(int(row))!r} samples UV map "
                                  f"{wanted!r}, which the mesh lacks; using the active render UV map")
            continue
        uvs[rows == row] = _read_uv(mesh, layer, loops)[rows == row]
    return uvs


def _lightmap_uv(mesh, loops: np.ndarray, uv_name: str, name: str) -> np.ndarray:
    """(t, 3, 2) float32 light-map UVs of a bake target; SceneError if the evaluated mesh lost the map."""
    layer = mesh.uv_layers.get(uv_name)
    if layer is None:
        raise SceneError(f"object {name!r}: its evaluated mesh has no UV map {uv_name!r} "
                         "(a modifier or geometry nodes dropped it?)")
    return _read_uv(mesh, layer, loops)


def _to_world(arrays: _MeshArrays, M: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray, bool]:
    """(positions (t, 3, 3) float64, unit normals (t, 3, 3) float64, mirrored) in world space.

    p_world = M @ p_object; normals by the inverse transpose of M. Corners whose
    normal vanishes (degenerate faces) take the face normal, else +Z. ``mirrored``
    (det M < 0) is returned so the caller swaps corners 1 and 2 of every per-corner array.
    """
    if not np.isfinite(M).all():
        raise SceneError(f"object {name!r}: non-finite world transform")
    if not np.isfinite(arrays.co).all():
        raise SceneError(f"object {name!r}: non-finite vertex position")
    t = len(arrays.material_local)
    positions = (arrays.co @ M[:3, :3].T + M[:3, 3])[arrays.vertices].reshape(t, 3, 3)
    linear = M[:3, :3]
    det = float(np.linalg.det(linear))
    normal_matrix = np.linalg.inv(linear).T if abs(det) > 1e-300 else np.linalg.pinv(linear).T
    n = arrays.corner_normals @ normal_matrix.T
    length = np.linalg.norm(n, axis=2, keepdims=True)
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    missing = ~(length[..., 0] > 0)
    if missing.any():
        e = np.cross(positions[:, 1] - positions[:, 0], positions[:, 2] - positions[:, 0])
        e_len = np.linalg.norm(e, axis=1, keepdims=True)
        face = np.divide(e, e_len, out=np.tile([0.0, 0.0, 1.0], (t, 1)), where=e_len > 0)
        if det < 0:  # the face normal of the swapped winding, which the caller makes
            face = -face
        n = np.where(missing[..., None], face[:, None, :], n)
    return positions, n, det < 0


def read_object_triangles(obj, matrix_world, name: str, table: MaterialTable, lightmap_uv_name: str | None,
                          timings: dict) -> _Chunk:
    """Copy one evaluated object's triangles out of Blender, in world space.

    Parameters
    ----------
    obj : evaluated bpy Object of a :data:`GEOMETRY_TYPES` type.
    matrix_world : (4, 4) object-to-world matrix (the instance's for instances).
    name : object name for messages.
    table : global material table; the object's slots are added to it.
    lightmap_uv_name : UV map to read as light-map UVs (bake targets), or None.
    timings : stage -> seconds; "materials" accumulates here.

    Returns
    -------
    _Chunk with positions (t, 3, 3) float64, unit normals (t, 3, 3) float32,
    texture UVs (t, 3, 2) float32 (active render UV map, zeros if none),
    global material rows (t,) int32, light-map UVs for targets and the shadow
    transmission (t,) float32 (1 everywhere when the object's Shadow visibility
    is off). Corners 1 and 2 are swapped when det(M) < 0 so the winding normal stays outward.

    Raises
    ------
    SceneError : non-finite vertex or transform; target whose evaluated mesh lost the light-map UV map.
    """
    M = np.array(matrix_world, np.float64).reshape(4, 4)
    mesh = obj.to_mesh()
    try:
        arrays = _mesh_arrays(mesh)
        start = time.perf_counter()
        slot_rows = _materials_of(obj, mesh, table)
        timings["materials"] = timings.get("materials", 0.0) + time.perf_counter() - start
        material = slot_rows[np.clip(arrays.material_local, 0, len(slot_rows) - 1)]
        uvs = _texture_uvs(mesh, arrays.loops, material, table, name)
        lightmap_uv = None if lightmap_uv_name is None else _lightmap_uv(mesh, arrays.loops, lightmap_uv_name, name)
    finally:
        obj.to_mesh_clear()
    positions_world, n, mirrored = _to_world(arrays, M, name)
    if mirrored:  # swap corners 1 and 2 so the winding normal stays outward
        swap = [0, 2, 1]
        positions_world, n, uvs = positions_world[:, swap], n[:, swap], uvs[:, swap]
        lightmap_uv = None if lightmap_uv is None else lightmap_uv[:, swap]
    casts_shadow = getattr(obj, "visible_shadow", True)
    transmission = table.transmission_of(material) if casts_shadow else np.ones(len(material), np.float32)
    return _Chunk(
        name=name,
        positions_world=positions_world,
        normals=n.astype(np.float32),
        uvs=np.ascontiguousarray(uvs, np.float32),
        material=material.astype(np.int32),
        lightmap_uv=lightmap_uv,
        transmission=transmission,
    )


def count_degenerate(positions: np.ndarray) -> int:
    """Number of triangles in (t, 3, 3) ``positions`` with zero area or collinear corners."""
    e1 = positions[:, 1] - positions[:, 0]
    e2 = positions[:, 2] - positions[:, 0]
    e3 = positions[:, 2] - positions[:, 1]
    twice_area = np.linalg.norm(np.cross(e1, e2), axis=1)
    longest2 = np.max(np.stack([(e * e).sum(1) for e in (e1, e2, e3)]), axis=0)
    return int(np.count_nonzero(twice_area <= DEGENERATE_RELATIVE_AREA * longest2))


class _Reader:
    """Step 3: what :func:`walk_render_objects` visits, read into chunks (geometry) and lights."""

    def __init__(self, lightmap_uv_name: str, warnings: list, timings: dict):
        self.lightmap_uv_name = lightmap_uv_name
        self.warnings = warnings
        self.timings = timings
        self.table = MaterialTable(warnings)
        self.chunks: list = []
        self.target_chunk: dict = {}  # session_uid -> index into chunks
        self.empty_targets: set = set()
        self.lights_world: list = []
        self.portals_world: list = []  # Cycles light portals: windows for the sun's and the world's photons
        timings.setdefault("geometry", 0.0)
        timings.setdefault("lights", 0.0)

    def __call__(self, obj, matrix_world, name: str, target_uid) -> None:
        start = time.perf_counter()
        if obj.type == "LIGHT":
            if is_portal(obj.data):
                portal = extract_portal(obj.data, np.array(matrix_world, np.float64), name, self.warnings)
                if portal is not None:
                    self.portals_world.append(portal)
            else:
                light = extract_light(obj.data, np.array(matrix_world, np.float64), name, self.warnings)
                if light is not None:
                    self.lights_world.append(light)
            self.timings["lights"] += time.perf_counter() - start
            return
        if obj.type not in GEOMETRY_TYPES:
            if obj.type in ("CURVES", "POINTCLOUD", "VOLUME", "GREASEPENCIL"):
                self.warnings.append(f"object {name!r}: {obj.type} objects are not extracted "
                                     "(they cast no shadow in the bake)")
            return
        uv_name = self.lightmap_uv_name if target_uid is not None else None
        chunk = read_object_triangles(obj, matrix_world, name, self.table, uv_name, self.timings)
        if len(chunk.material):
            if target_uid is not None:
                self.target_chunk[target_uid] = len(self.chunks)
            self.chunks.append(chunk)
        elif target_uid is not None:
            self.empty_targets.add(target_uid)
        self.timings["geometry"] += time.perf_counter() - start


# --------------------------------------------------------------------------- 4. geometry and targets
def assemble_geometry(chunks: list, target: np.ndarray) -> tuple[Geometry, np.ndarray]:
    """(Geometry in scene-local coordinates, origin_world (3,) float64) of all chunks.

    target : (T,) int32 bake-target row of every triangle (:func:`assemble_targets`).
    """
    if chunks:
        columns = {key: np.concatenate([getattr(c, key) for c in chunks])
                   for key in ("positions_world", "normals", "uvs", "material", "transmission")}
    else:
        columns = {"positions_world": np.zeros((0, 3, 3)), "normals": np.zeros((0, 3, 3), np.float32),
                   "uvs": np.zeros((0, 3, 2), np.float32), "material": np.zeros(0, np.int32),
                   "transmission": np.zeros(0, np.float32)}
    positions_local, origin_world = recentre(columns["positions_world"])
    geometry = Geometry(positions=positions_local, normals=columns["normals"], uvs=columns["uvs"],
                        material=columns["material"], target=target, transmission=columns["transmission"])
    return geometry, origin_world


def degenerate_counts(chunks: list, warnings: list) -> dict:
    """Object name -> count of degenerate triangles (only objects that have some), with a warning each."""
    degenerate: dict = {}
    for chunk in chunks:
        count = count_degenerate(chunk.positions_world)
        if count:
            degenerate[chunk.name] = degenerate.get(chunk.name, 0) + count
    for name, count in degenerate.items():
        warnings.append(f"object {name!r}: {count} degenerate (zero-area) triangles kept as occluders, not baked")
    return degenerate


def shared_lightmap_triangles(lightmap_uv: np.ndarray, resolution: tuple) -> int:
    """Number of triangles of (t, 3, 2) light-map UVs that share a texel sample with another one.

    A modifier that copies a mesh (Array, Mirror) copies its light-map UVs too, so the
    copies land on the same texels; an unwrap's own charts never overlap. Tested on
    the light map's own grid, 2 x 2 points per texel (``core.raster.overlapping``).
    """
    if len(lightmap_uv) == 0:
        return 0
    return int(overlapping(lightmap_uv, int(resolution[0]), int(resolution[1]), samples_per_axis=2).sum())


def _replicating_modifiers(ob) -> str:
    """Names of the object's enabled modifiers that copy geometry, for messages."""
    kinds = {"ARRAY", "MIRROR", "NODES", "SCREW", "PARTICLE_INSTANCE"}
    found = [f"{m.name!r} ({m.type})" for m in ob.modifiers if m.type in kinds and m.show_viewport]
    return ", ".join(found) if found else "a modifier"


def _base_shared_fraction(ob, uv_name: str, resolution: tuple) -> float:
    """Fraction of the original (unmodified) mesh's triangles whose light-map UV triangle repeats."""
    mesh = ob.data
    layer = mesh.uv_layers.get(uv_name)
    t = len(mesh.loop_triangles)
    if layer is None or t == 0:
        return 0.0
    loops = np.empty(3 * t, np.int32)
    mesh.loop_triangles.foreach_get("loops", loops)
    return shared_lightmap_triangles(_read_uv(mesh, layer, loops), resolution) / t


def _refusal(ob, chunk: _Chunk | None, reader: _Reader, uid, uv_name: str, resolution: tuple) -> str | None:
    """Why the target ``ob`` gets no light map, or None when it can be baked.

    Copies are detected as light-map UV triangles that repeat more often in the evaluated
    mesh than in the object's own mesh (an unwrap never repeats; subdivision keeps the ratio).
    """
    if chunk is None:
        return "has no triangles" if uid in reader.empty_targets else "not found in the evaluated scene"
    t = len(chunk.material)
    shared = shared_lightmap_triangles(chunk.lightmap_uv, resolution)
    if shared / t > _base_shared_fraction(ob, uv_name, resolution) + SHARED_LIGHTMAP_UV_FRACTION:
        return (f"{shared} of its {t} triangles share light-map texels with copies made by "
                f"{_replicating_modifiers(ob)}; apply the modifier (Object > Apply) or make the copies "
                f"separate objects, then bake again")
    return None


def assemble_targets(targets: _Targets, reader: _Reader, resolutions: dict, uv_name: str,
                     warnings: list) -> tuple[list, list, np.ndarray]:
    """(BakeTargets and object names in ``bake_objects`` order, (T,) int32 target row per triangle or -1).

    A target with no triangles, missing from the evaluated scene or whose copies share
    light-map texels is skipped with a warning naming it.
    """
    offsets = np.cumsum([0] + [len(c.material) for c in reader.chunks])
    target = np.full(offsets[-1], -1, np.int32)
    out, names, refused = [], [], []
    for uid, ob in targets.bake.items():
        index = reader.target_chunk.get(uid)
        chunk = None if index is None else reader.chunks[index]
        if ob.name not in resolutions:
            raise SceneError(f"object {ob.name!r}: no light-map resolution given")
        width, height = resolutions[ob.name]
        reason = _refusal(ob, chunk, reader, uid, uv_name, (width, height))
        if reason is not None:
            warnings.append(f"object {ob.name!r}: {reason}; no light map baked")
            refused.append(f"object {ob.name!r}: {reason}")
            continue
        triangles = np.arange(offsets[index], offsets[index + 1], dtype=np.int64)
        if ((chunk.lightmap_uv < -1e-4) | (chunk.lightmap_uv > 1 + 1e-4)).any():
            warnings.append(f"object {ob.name!r}: light-map UV map {uv_name!r} has coordinates outside [0, 1]")
        target[triangles] = len(out)
        out.append(BakeTarget(name=ob.name, triangles=triangles, lightmap_uv=chunk.lightmap_uv,
                              width=int(width), height=int(height)))
        names.append(ob.name)
    if not out:
        raise SceneError("no bakeable mesh among the bake objects: " + "; ".join(refused))
    return out, names, target


# --------------------------------------------------------------------------- 5. the scene
def assemble_scene(geometry: Geometry, origin_world: np.ndarray, reader: _Reader, bake_targets: list,
                   world_datablock, warnings: list) -> Scene:
    """The core scene: materials, lights recentred with ``origin_world``, world; SceneError if nothing emits."""
    materials, textures = reader.table.build()
    world = extract_world(world_datablock, warnings)
    scene = Scene(
        geometry=geometry,
        materials=materials,
        textures=textures,
        lights=tuple(recentre_light(light, origin_world) for light in reader.lights_world),
        world=world,
        targets=tuple(bake_targets),
        origin_world=origin_world,
        portals=tuple(recentre_light(portal, origin_world) for portal in reader.portals_world),
    )
    if not scene.has_light():
        raise SceneError(
            "nothing emits light: no light with power, no emissive material and a black world "
            "(add a light, an emissive material or a world colour)"
        )
    return scene


def extract_scene(depsgraph, bake_objects, lightmap_uv_name: str, resolutions: dict) -> Extraction:
    """Build the core scene from Blender's evaluated depsgraph.

    Parameters
    ----------
    depsgraph : bpy.types.Depsgraph, evaluated (``context.evaluated_depsgraph_get()``).
    bake_objects : iterable of original mesh objects that receive light maps; each
        carries a UV map named ``lightmap_uv_name``.
    lightmap_uv_name : name of the light-map UV map, e.g. "PDIC_Lightmap".
    resolutions : object name -> (width, height) light-map texels, for every bake object.

    Returns
    -------
    Extraction : the scene (scene-local coordinates, lights recentred with the same
        origin), warnings, target object names in ``scene.targets`` order, and
        degenerate-triangle counts per object.

    Raises
    ------
    SceneError : no bakeable mesh among ``bake_objects``; a non-finite vertex
        (naming the object); a target whose evaluated mesh lost its light-map UV
        map; a missing resolution; nothing in the scene emits light.
    """
    warnings: list = []
    timings: dict = {}
    clock = time.perf_counter()
    targets = choose_targets(depsgraph.view_layer, bake_objects, warnings)
    timings["visibility"] = time.perf_counter() - clock

    reader = _Reader(lightmap_uv_name, warnings, timings)
    walk_render_objects(depsgraph, targets, reader, warnings)
    timings["geometry"] -= timings.get("materials", 0.0)

    clock = time.perf_counter()
    degenerate = degenerate_counts(reader.chunks, warnings)
    bake_targets, names, target = assemble_targets(targets, reader, resolutions, lightmap_uv_name, warnings)
    geometry, origin_world = assemble_geometry(reader.chunks, target)
    scene = assemble_scene(geometry, origin_world, reader, bake_targets, depsgraph.scene.world, warnings)
    timings["assemble"] = time.perf_counter() - clock
    return Extraction(scene=scene, warnings=warnings, target_objects=names,
                      degenerate_triangles=degenerate, timings=timings)
