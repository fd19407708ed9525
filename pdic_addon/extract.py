"""Scene extraction: Blender's evaluated depsgraph -> :class:`core.scene.Scene`.

This is the one place where scene data leaves Blender (STYLE.md, principle 1):
every evaluated object is turned into a mesh once (``to_mesh`` /
``to_mesh_clear``), its arrays are copied with ``foreach_get`` into
preallocated typed numpy arrays, transformed to world space in float64 and
finally recentred around the scene's bounding-box centre.

What renders is what Cycles renders: objects hidden from render
(``hide_render``), objects in collections hidden from render and excluded
collections are skipped. Collection, vertex/face, particle and geometry-node
instances are extracted as occluders and emitters; only an original object of
``bake_objects`` (its non-instance evaluation) becomes a bake target.

Background-mode caveat: ``Context.evaluated_depsgraph_get()`` is a *viewport*
depsgraph. Objects hidden in the viewport but rendered (eye icon, or
"Disable in Viewports") are not among its instances; they are added here
from their evaluation (eye icon) or, when the depsgraph did not evaluate them
("Disable in Viewports"), from their unmodified mesh with a warning.
Modifiers are evaluated with their viewport settings (levels, visibility).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..core.scene import BakeTarget, Geometry, Scene, SceneError, SunLight, recentre
from .extract_lights import extract_light, extract_world
from .extract_materials import MaterialTable

GEOMETRY_TYPES = frozenset({"MESH", "CURVE", "SURFACE", "FONT", "META"})
"""Object types converted through ``to_mesh()``; other types (hair curves,
point clouds, volumes, grease pencil) are not extracted."""

DEGENERATE_RELATIVE_AREA = 1e-12
"""A triangle is degenerate when |e1 x e2| <= this * (longest edge)^2 (zero area or collinear corners)."""


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


# --------------------------------------------------------------------------- visibility
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


# --------------------------------------------------------------------------- geometry
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
    global material rows (t,) int32, and light-map UVs for targets. Corners 1
    and 2 are swapped when det(M) < 0 so the winding normal stays outward.

    Raises
    ------
    SceneError : non-finite vertex or transform; target whose evaluated mesh lost the light-map UV map.
    """
    M = np.array(matrix_world, np.float64).reshape(4, 4)
    mesh = obj.to_mesh()
    try:
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
        render_layer = next((layer for layer in mesh.uv_layers if layer.active_render), None)
        uvs = _read_uv(mesh, render_layer, loops) if render_layer is not None else np.zeros((t, 3, 2), np.float32)
        lightmap_uv = None
        if lightmap_uv_name is not None:
            layer = mesh.uv_layers.get(lightmap_uv_name)
            if layer is None:
                raise SceneError(
                    f"object {name!r}: its evaluated mesh has no UV map {lightmap_uv_name!r} "
                    "(a modifier or geometry nodes dropped it?)"
                )
            lightmap_uv = _read_uv(mesh, layer, loops)
        start = time.perf_counter()
        slot_rows = _materials_of(obj, mesh, table)
        timings["materials"] = timings.get("materials", 0.0) + time.perf_counter() - start
        # Textures whose UV Map node names another UV map read that layer on their triangles.
        rows = slot_rows[np.clip(material_local, 0, len(slot_rows) - 1)]
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
    finally:
        obj.to_mesh_clear()

    # -- world space, float64: p_world = M @ p_object
    if not np.isfinite(M).all():
        raise SceneError(f"object {name!r}: non-finite world transform")
    p_object = co.astype(np.float64).reshape(-1, 3)
    if not np.isfinite(p_object).all():
        raise SceneError(f"object {name!r}: non-finite vertex position")
    positions_world = (p_object @ M[:3, :3].T + M[:3, 3])[vertices].reshape(t, 3, 3)

    # -- normals by the inverse transpose of M, normalised
    linear = M[:3, :3]
    det = float(np.linalg.det(linear))
    normal_matrix = np.linalg.inv(linear).T if abs(det) > 1e-300 else np.linalg.pinv(linear).T
    n = corner_normals.astype(np.float64).reshape(-1, 3)[loops].reshape(t, 3, 3) @ normal_matrix.T
    length = np.linalg.norm(n, axis=2, keepdims=True)
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)

    material = slot_rows[np.clip(material_local, 0, len(slot_rows) - 1)]

    # -- mirrored transform: swap corners 1 and 2 so the winding normal stays outward
    if det < 0:
        swap = [0, 2, 1]
        positions_world = positions_world[:, swap]
        n = n[:, swap]
        uvs = uvs[:, swap]
        if lightmap_uv is not None:
            lightmap_uv = lightmap_uv[:, swap]

    # -- corners with no usable normal (degenerate faces): the face normal, else +Z
    missing = ~(length[..., 0] > 0)
    if missing.any():
        e = np.cross(positions_world[:, 1] - positions_world[:, 0], positions_world[:, 2] - positions_world[:, 0])
        e_len = np.linalg.norm(e, axis=1, keepdims=True)
        face = np.divide(e, e_len, out=np.tile([0.0, 0.0, 1.0], (t, 1)), where=e_len > 0)
        n = np.where(missing[..., None], face[:, None, :], n)

    return _Chunk(
        name=name,
        positions_world=positions_world,
        normals=n.astype(np.float32),
        uvs=np.ascontiguousarray(uvs, np.float32),
        material=material.astype(np.int32),
        lightmap_uv=lightmap_uv,
    )


def count_degenerate(positions: np.ndarray) -> int:
    """Number of triangles in (t, 3, 3) ``positions`` with zero area or collinear corners."""
    e1 = positions[:, 1] - positions[:, 0]
    e2 = positions[:, 2] - positions[:, 0]
    e3 = positions[:, 2] - positions[:, 1]
    twice_area = np.linalg.norm(np.cross(e1, e2), axis=1)
    longest2 = np.max(np.stack([(e * e).sum(1) for e in (e1, e2, e3)]), axis=0)
    return int(np.count_nonzero(twice_area <= DEGENERATE_RELATIVE_AREA * longest2))


# --------------------------------------------------------------------------- the scene
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
    timings: dict = {}
    warnings: list = []
    table = MaterialTable(warnings)
    clock = time.perf_counter()

    # -- which objects render, which get light maps
    visible = render_visible_objects(depsgraph.view_layer)
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
    timings["visibility"] = time.perf_counter() - clock

    chunks: list = []
    target_chunk: dict = {}  # session_uid -> index into chunks
    lights_world: list = []
    seen: set = set()
    empty_targets: set = set()
    geometry_time = lights_time = 0.0

    def take(obj, matrix_world, name: str, target_uid):
        nonlocal geometry_time, lights_time
        start = time.perf_counter()
        if obj.type == "LIGHT":
            light = extract_light(obj.data, np.array(matrix_world, np.float64), name, warnings)
            if light is not None:
                lights_world.append(light)
            lights_time += time.perf_counter() - start
            return
        if obj.type not in GEOMETRY_TYPES:
            if obj.type in ("CURVES", "POINTCLOUD", "VOLUME", "GREASEPENCIL"):
                warnings.append(f"object {name!r}: {obj.type} objects are not extracted (they cast no shadow in the bake)")
            return
        chunk = read_object_triangles(obj, matrix_world, name, table,
                                      lightmap_uv_name if target_uid is not None else None, timings)
        if len(chunk.material):
            if target_uid is not None:
                target_chunk[target_uid] = len(chunks)
            chunks.append(chunk)
        elif target_uid is not None:
            empty_targets.add(target_uid)
        geometry_time += time.perf_counter() - start

    # -- every evaluated object and instance
    for inst in depsgraph.object_instances:
        obj = inst.object
        orig = obj.original
        if inst.is_instance:
            instancer = inst.parent.original if inst.parent is not None else None
            if orig.hide_render or (instancer is not None and instancer.session_uid not in visible):
                continue
            take(obj, inst.matrix_world, f"{inst.parent.name}/{obj.name}" if inst.parent else obj.name, None)
        else:
            uid = orig.session_uid
            if uid not in visible:
                continue
            seen.add(uid)
            if not _instancer_renders_itself(orig):
                continue
            take(obj, inst.matrix_world, obj.name, uid if uid in bake else None)

    # -- objects that render but the viewport depsgraph does not list (hidden in the viewport)
    for uid, ob in visible.items():
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
        take(evaluated, matrix_world, ob.name, uid if uid in bake else None)

    timings["geometry"] = geometry_time - timings.get("materials", 0.0)
    timings["lights"] = lights_time

    # -- assemble, recentre (lights with the same origin)
    clock = time.perf_counter()
    materials, textures = table.build()
    clock_world = time.perf_counter()
    world = extract_world(depsgraph.scene.world, warnings)
    timings["lights"] += time.perf_counter() - clock_world

    if chunks:
        positions_world = np.concatenate([c.positions_world for c in chunks])
        normals = np.concatenate([c.normals for c in chunks])
        uvs = np.concatenate([c.uvs for c in chunks])
        material = np.concatenate([c.material for c in chunks])
    else:
        positions_world = np.zeros((0, 3, 3))
        normals = np.zeros((0, 3, 3), np.float32)
        uvs = np.zeros((0, 3, 2), np.float32)
        material = np.zeros(0, np.int32)
    positions_local, origin_world = recentre(positions_world)
    target = np.full(len(positions_local), -1, np.int32)
    offsets = np.cumsum([0] + [len(c.material) for c in chunks])

    degenerate: dict = {}
    for chunk in chunks:
        count = count_degenerate(chunk.positions_world)
        if count:
            degenerate[chunk.name] = degenerate.get(chunk.name, 0) + count
    for name, count in degenerate.items():
        warnings.append(f"object {name!r}: {count} degenerate (zero-area) triangles kept as occluders, not baked")

    targets, target_objects = [], []
    for uid, ob in bake.items():  # bake_objects order
        index = target_chunk.get(uid)
        if index is None:
            if uid in empty_targets:
                warnings.append(f"object {ob.name!r}: has no triangles; no light map baked")
            else:
                warnings.append(f"object {ob.name!r}: not found in the evaluated scene; no light map baked")
            continue
        chunk = chunks[index]
        if ob.name not in resolutions:
            raise SceneError(f"object {ob.name!r}: no light-map resolution given")
        width, height = resolutions[ob.name]
        triangles = np.arange(offsets[index], offsets[index + 1], dtype=np.int64)
        outside = (chunk.lightmap_uv < -1e-4) | (chunk.lightmap_uv > 1 + 1e-4)
        if outside.any():
            warnings.append(f"object {ob.name!r}: light-map UV map {lightmap_uv_name!r} has coordinates outside [0, 1]")
        target[triangles] = len(targets)
        targets.append(BakeTarget(name=ob.name, triangles=triangles, lightmap_uv=chunk.lightmap_uv,
                                  width=int(width), height=int(height)))
        target_objects.append(ob.name)
    if not targets:
        raise SceneError("no bakeable mesh among the bake objects: none of them has triangles in the evaluated scene")

    lights = tuple(l if isinstance(l, SunLight) else replace(l, position=l.position - origin_world)
                   for l in lights_world)
    scene = Scene(
        geometry=Geometry(positions=positions_local, normals=normals, uvs=uvs, material=material, target=target),
        materials=materials,
        textures=textures,
        lights=lights,
        world=world,
        targets=tuple(targets),
        origin_world=origin_world,
    )
    if not scene.has_light():
        raise SceneError(
            "nothing emits light: no light with power, no emissive material and a black world "
            "(add a light, an emissive material or a world colour)"
        )
    timings["assemble"] = time.perf_counter() - clock
    return Extraction(scene=scene, warnings=warnings, target_objects=target_objects,
                      degenerate_triangles=degenerate, timings=timings)
