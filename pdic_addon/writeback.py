"""Writing bake results back into Blender, non-destructively, and taking them out again.

What a bake adds to the file, all of it owned and tagged by PDIC:

* a UV map ``PDIC_Lightmap`` on each baked mesh (:mod:`.uvmaps`);
* an image ``PDIC_<object>`` per object: a float OpenEXR file in the output
  folder (colour space Non-Color, i.e. linear values), or packed into the
  .blend when the .blend has never been saved; tagged ``image["pdic_owner"]``;
* per object and material slot a copy of the slot's material,
  ``<material>.PDIC.<object>``, tagged ``material["pdic_owner"]``, assigned through
  an OBJECT-linked slot. Its tree shows ``light map x base colour`` through an
  Emission shader, so Material Preview and EEVEE show the baked lighting. The
  user's materials, their node trees and the mesh's own material slots are
  never modified; the copy remembers how the slot was linked before.

:func:`set_shading` switches objects between their original shading and the
baked lighting; :func:`clear` removes everything above (files on disk stay).
"""
from __future__ import annotations

import hashlib
import os
import shutil
import uuid
from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np

from ..core import atomic
from . import uvmaps

OWNER = "pdic_owner"           # ID property: name of the object a PDIC datablock belongs to
SLOT = "pdic_slot"             # material copies: slot index
SOURCE = "pdic_source"         # material copies: the user's material (ID pointer; absent for an empty slot)
USER_LINK = "pdic_user_link"   # material copies: the slot's link before the bake, 'DATA' or 'OBJECT'
USER_OBJECT_MATERIAL = "pdic_user_object_material"  # the object-level material before the bake (ID pointer)
OWNER_OBJECT = "pdic_object"   # the owning object itself (ID pointer): ownership survives renaming it
FINGERPRINT = "pdic_fingerprint"  # material copies: digest of the tree as built (an edit changes it)
EDITED_SUFFIX = " (edited)"    # an edited copy is kept under its name plus this when its bake is replaced
IMAGE_PREFIX = "PDIC_"
COPY_INFIX = ".PDIC."
FORMATS = {"EXR_HALF": "16", "EXR_FLOAT": "32"}
DEFAULT_BASE_COLOR = (0.8, 0.8, 0.8)  # Blender's default surface


class WritebackError(ValueError):
    """The results cannot be written; the message names the path/object/material."""


# --------------------------------------------------------------------------- output folder
@dataclass(frozen=True)
class OutputPlan:
    """Where images go. ``directory`` is None when images are packed into the .blend."""

    directory: Path | None
    pack: bool
    message: str = ""


def plan_output(folder: str, blend_path: str | None = None) -> OutputPlan:
    """Validate the output folder without changing anything.

    folder : Blender path, ``//`` = the .blend's folder. A relative (``//``) folder
        with an unsaved .blend means: pack the images into the .blend.
    blend_path : the .blend's path ("" if unsaved); defaults to ``bpy.data.filepath``.

    Raises WritebackError naming the path when it is not a folder or cannot be written.
    """
    blend_path = bpy.data.filepath if blend_path is None else blend_path
    folder = (folder or "").strip()
    if not folder:
        raise WritebackError("output folder is empty; set one (e.g. //pdic_lightmaps/)")
    if folder.startswith("//") and not blend_path:
        return OutputPlan(None, True, "the .blend is not saved: light maps are packed into the file "
                                      "(save the .blend to write them to " + folder + ")")
    path = Path(bpy.path.abspath(folder, start=os.path.dirname(blend_path) or None) if folder.startswith("//")
                else os.path.expanduser(folder)).resolve()
    probe = path
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        raise WritebackError(f"output folder {str(path)!r} is not usable: {str(probe)!r} is not a folder")
    if not os.access(probe, os.W_OK | os.X_OK) or not _can_create_in(probe, path):
        raise WritebackError(f"output folder {str(path)!r} is read-only or cannot be created")
    return OutputPlan(path, False, f"light maps written to {path}")


def _can_create_in(existing: Path, target: Path) -> bool:
    """Try creating (and removing at once) a file in ``existing``; root ignores permission bits."""
    try:
        fd = os.open(existing / f".pdic-probe-{uuid.uuid4().hex}", os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)
    except OSError:
        return False
    os.close(fd)
    for name in os.listdir(existing):
        if name.startswith(".pdic-probe-"):
            try:
                os.unlink(existing / name)
            except OSError:
                pass
    return True


def ensure_directory(plan: OutputPlan, txn) -> None:
    """Create the output folder (and parents) if missing; undo removes what it created."""
    if plan.pack or plan.directory.exists():
        return
    created = []
    p = plan.directory
    while not p.exists():
        created.append(p)
        p = p.parent
    try:
        plan.directory.mkdir(parents=True)
    except OSError as e:
        raise WritebackError(f"cannot create output folder {str(plan.directory)!r}: {e.strerror}") from e

    def undo():
        for d in created:  # deepest first; only if still empty
            try:
                d.rmdir()
            except OSError:
                pass

    txn.add(undo, f"remove folder {plan.directory}")


def replace_file(path: Path, write, txn) -> None:
    """Write ``path`` atomically with ``write(tmp_path)``; undo puts the previous file back, commit drops it.

    The previous file stays in place until the new one is complete, so a failed write
    changes nothing on disk.
    """
    def write_and_keep_previous(tmp: Path) -> None:
        write(tmp)
        if path.exists():  # a second name for the previous file: ``path`` itself is never missing
            try:
                os.link(path, backup)
            except OSError:  # file systems without hard links
                shutil.copy2(path, backup)

    backup = atomic.temporary_sibling(path, "backup")
    try:
        atomic.write_atomic(path, write_and_keep_previous)
    except OSError as e:
        if backup.exists():
            backup.unlink()
        raise WritebackError(f"cannot write {str(path)!r}: {atomic.describe_os_error(e, path.parent)}") from e
    except RuntimeError as e:  # Blender's image writer
        if backup.exists():
            backup.unlink()
        raise WritebackError(f"cannot write {str(path)!r}: {_runtime_message(e, path.parent)}") from e

    def undo():
        if backup.exists():
            os.replace(backup, path)
        elif path.exists():
            path.unlink()

    def commit():
        if backup.exists():
            backup.unlink()

    txn.add(undo, f"restore file {path}", commit=commit)


def _runtime_message(error: RuntimeError, folder: Path) -> str:
    """Blender reports a full disk as a generic error (e.g. "Invalid argument"): say what it is."""
    free = None
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        pass
    if free is not None and free < 1 << 20:
        return atomic.describe_os_error(OSError(28, "No space left on device"), folder)
    return str(error)


# --------------------------------------------------------------------------- images
def image_name(object_name: str) -> str:
    return IMAGE_PREFIX + object_name


def file_key(name: str) -> str:
    """A file-name-safe key for ``name``: stable, and distinct for distinct names.

    Plain names (ASCII letters, digits, ``_`` and ``-``) are their own key; any other
    name gets its cleaned form plus 8 hex digits of its sha1 (``Wall.001`` ->
    ``Wall_001.3c6e1b2a``), so ``Wall.001``/``Wall_001``, ``Wall 1``/``Wall_1`` and
    ``Mèsa``/``Mésa`` never share a file. Keys of plain names never contain ``.``.
    """
    clean = bpy.path.clean_name(name)
    if clean == name and name.isascii():
        return name
    return f"{clean}.{hashlib.sha1(name.encode('utf-8')).hexdigest()[:8]}"


def blend_key(blend_path: str | None = None) -> str:
    """The .blend's part of output file names ("" for an unsaved file): its name without ``.blend``."""
    blend_path = bpy.data.filepath if blend_path is None else blend_path
    return file_key(Path(blend_path).stem) if blend_path else ""


def image_filename(object_name: str, blend_path: str | None = None) -> str:
    """``<blend>.PDIC_<object>.exr``: unique per object and per .blend, the same at every re-bake
    (two .blend files sharing an output folder never overwrite each other's maps)."""
    prefix = blend_key(blend_path)
    return (prefix + "." if prefix else "") + IMAGE_PREFIX + file_key(object_name) + ".exr"


def _remove_image(image):
    if image is not None and image.name in bpy.data.images and bpy.data.images[image.name] == image:
        bpy.data.images.remove(image)


def _save_exr(pixels: np.ndarray, path: Path, color_depth: str) -> None:
    """Save (H, W, 4) float32 linear RGBA (row 0 bottom) as OpenEXR (ZIP) without colour transforms."""
    h, w, _ = pixels.shape
    tmp = bpy.data.images.new(".pdic_save", w, h, alpha=True, float_buffer=True)
    scene = bpy.data.scenes.new(".pdic_save")
    try:
        tmp.colorspace_settings.name = "Non-Color"
        tmp.pixels.foreach_set(pixels.ravel())
        s = scene.render.image_settings
        s.file_format = "OPEN_EXR"
        s.color_mode = "RGBA"
        s.color_depth = color_depth
        s.exr_codec = "ZIP"
        tmp.save_render(str(path), scene=scene)
    finally:
        bpy.data.scenes.remove(scene)
        bpy.data.images.remove(tmp)


def write_image(object_name: str, pixels: np.ndarray, plan: OutputPlan, image_format: str, txn,
                name: str | None = None):
    """Create the light-map image of one object; returns (image, file path relative to the folder or "").

    pixels : (H, W, 4) float32 linear RGBA, row 0 = bottom, finite.
    name : datablock name (defaults to ``PDIC_<object>``; a re-bake passes a temporary one).
    """
    pixels = np.ascontiguousarray(pixels, dtype=np.float32)
    if pixels.ndim != 3 or pixels.shape[2] != 4:
        raise WritebackError(f"light map of {object_name!r}: expected (H, W, 4) pixels, got {pixels.shape}")
    if not np.isfinite(pixels).all():
        raise WritebackError(f"light map of {object_name!r} has NaN or infinite texels")
    if image_format not in FORMATS:
        raise WritebackError(f"unknown image format {image_format!r}; one of {', '.join(FORMATS)}")
    h, w, _ = pixels.shape
    name = name or image_name(object_name)
    if plan.pack:
        image = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True)
        txn.add(lambda: _remove_image(image), f"remove image {name}")
        image.colorspace_settings.name = "Non-Color"
        image.pixels.foreach_set(pixels.ravel())
        image.file_format = "OPEN_EXR"
        image.filepath_raw = "//" + image_filename(object_name)
        image.pack()
        relpath = ""
    else:
        path = plan.directory / image_filename(object_name)
        replace_file(path, lambda p: _save_exr(pixels, p, FORMATS[image_format]), txn)
        image = bpy.data.images.load(str(path), check_existing=False)
        txn.add(lambda: _remove_image(image), f"remove image {name}")
        image.name = name
        image.colorspace_settings.name = "Non-Color"
        if bpy.data.filepath:
            try:
                image.filepath_raw = bpy.path.relpath(str(path))
            except ValueError:  # another drive (Windows)
                pass
        relpath = path.name
    image.alpha_mode = "CHANNEL_PACKED"  # alpha is coverage, not opacity: never premultiply
    image.use_half_precision = image_format == "EXR_HALF"
    image.use_fake_user = True
    tag_owner(image, object_name)
    return image, relpath


# --------------------------------------------------------------------------- ownership
def tag_owner(idblock, object_name: str) -> None:
    """Mark ``idblock`` as PDIC's output for the object ``object_name`` (by name and by pointer)."""
    idblock[OWNER] = object_name
    obj = bpy.data.objects.get(object_name)
    if obj is not None:
        idblock[OWNER_OBJECT] = obj


def is_pdic(idblock) -> bool:
    return idblock is not None and OWNER in idblock.keys()


def owner_of(idblock):
    """The object a PDIC datablock belongs to (followed through renames), or None if it is gone.

    An object deleted (or joined into another) while a copy still points at it lingers
    in ``bpy.data`` without a scene: that counts as gone.
    """
    obj = idblock.get(OWNER_OBJECT)
    if obj is None:
        obj = bpy.data.objects.get(idblock[OWNER])
    return obj if obj is not None and obj.users_scene else None


def _owned_by(idblock, owner) -> bool:
    if owner is None:
        return True
    obj = bpy.data.objects.get(owner) if isinstance(owner, str) else owner
    pointer = idblock.get(OWNER_OBJECT)
    if pointer is not None and obj is not None:
        return pointer == obj
    return idblock[OWNER] == (owner if isinstance(owner, str) else owner.name)


def owned_materials(owner=None) -> list:
    """PDIC material copies of ``owner`` (an object or its name; None = all)."""
    return [m for m in bpy.data.materials if is_pdic(m) and _owned_by(m, owner)]


def owned_images(owner=None) -> list:
    """PDIC light-map images of ``owner`` (an object or its name; None = all)."""
    return [i for i in bpy.data.images if is_pdic(i) and _owned_by(i, owner)]


def orphaned_owners() -> set:
    """Owner names of PDIC datablocks whose object no longer exists (deleted, or joined into another)."""
    return {d[OWNER] for d in (*owned_materials(), *owned_images()) if owner_of(d) is None}


# --------------------------------------------------------------------------- material copies
def copy_name(material_name: str, object_name: str) -> str:
    return f"{material_name}{COPY_INFIX}{object_name}"


def _object_material(slot):
    """The slot's object-level material, whatever the slot's link (restores the link)."""
    if slot.link == "OBJECT":
        return slot.material
    slot.link = "OBJECT"
    material = slot.material
    slot.link = "DATA"
    return material


def _surface_node(material):
    """The shader node feeding the active output's Surface (through reroutes), or None."""
    if material is None or material.node_tree is None:
        return None
    tree = material.node_tree
    outputs = [n for n in tree.nodes if n.type == "OUTPUT_MATERIAL" and n.target in ("ALL", "EEVEE")]
    output = next((n for n in outputs if n.is_active_output), outputs[0] if outputs else None)
    if output is None or not output.inputs["Surface"].is_linked:
        return None
    node = output.inputs["Surface"].links[0].from_node
    while node.type == "REROUTE" and node.inputs[0].is_linked:
        node = node.inputs[0].links[0].from_node
    return node


def _base_color_source(material):
    """(from_socket or None, constant rgb) feeding the base colour of ``material``'s surface."""
    fallback = tuple(material.diffuse_color[:3]) if material is not None else DEFAULT_BASE_COLOR
    node = _surface_node(material)
    if node is None:
        return None, fallback
    if node.type == "EMISSION":  # reflects nothing (as extraction reads it): only its glow shows
        return None, (0.0, 0.0, 0.0)
    socket = {"BSDF_PRINCIPLED": "Base Color", "BSDF_DIFFUSE": "Color"}.get(node.type)
    if socket is None:
        return None, fallback
    inp = node.inputs[socket]
    if inp.is_linked:
        return inp.links[0].from_socket, fallback
    return None, tuple(inp.default_value[:3])


def _constant_emission(material):
    """(3,) constant emitted radiance of a Principled/Emission surface, zeros if none or not constant."""
    zero = (0.0, 0.0, 0.0)
    surface = _surface_node(material)
    if surface is not None and surface.type == "EMISSION":
        color, strength = surface.inputs["Color"], surface.inputs["Strength"]
    else:
        node = next((n for n in material.node_tree.nodes if n.type == "BSDF_PRINCIPLED"), None) \
            if material is not None and material.node_tree is not None else None
        if node is None:
            return zero
        color, strength = node.inputs["Emission Color"], node.inputs["Emission Strength"]
    if color.is_linked or strength.is_linked:
        return zero
    return tuple(float(c) * float(strength.default_value) for c in color.default_value[:3])


NODE_SETTINGS = ("operation", "blend_type", "data_type", "interpolation", "extension", "uv_map", "target",
                 "is_active_output", "mute")
"""Node attributes (besides socket values and links) whose change counts as an edit of a copy."""


def fingerprint(material) -> str:
    """Digest of ``material``'s node tree (nodes, their settings and socket values, links).

    Stored on a copy when it is built; a different digest later means the user edited
    the copy (:func:`is_edited`).
    """
    tree = material.node_tree
    if tree is None:
        return ""
    rows = []
    for n in sorted(tree.nodes, key=lambda n: n.name):
        values = [(s.identifier, _rounded(s.default_value)) for s in n.inputs if hasattr(s, "default_value")]
        settings = [(a, str(getattr(n, a))) for a in NODE_SETTINGS if hasattr(n, a)]
        image = getattr(n, "image", None)
        rows.append((n.bl_idname, n.name, values, settings, image is not None and is_pdic(image)))
    links = sorted((l.from_node.name, l.from_socket.identifier, l.to_node.name, l.to_socket.identifier)
                   for l in tree.links)
    return hashlib.sha1(repr((rows, links)).encode()).hexdigest()


def _rounded(value):
    if hasattr(value, "__len__") and not isinstance(value, str):
        return tuple(round(float(x), 5) for x in value)
    return round(value, 5) if isinstance(value, float) else value


def is_edited(copy) -> bool:
    """True if the user changed a PDIC copy's nodes after the bake built it."""
    return FINGERPRINT in copy and copy[FINGERPRINT] != fingerprint(copy)


def build_copy(obj, slot_index: int, source, image, name: str, txn=None):
    """A new material showing ``light map x base colour`` of ``source`` (None = empty slot).

    Tree: UV Map (PDIC_Lightmap) -> Image Texture (light map, Non-Color) ->
    Vector Math MULTIPLY with the source's base colour (its linked socket or
    constant) [-> ADD constant emission] -> Emission (strength 1) -> Material Output.
    ``txn`` records the copy's removal as soon as it exists.
    """
    if source is not None:
        copy = source.copy()
        for key in list(copy.keys()):  # do not inherit the user's custom properties' PDIC tags
            if key.startswith("pdic_"):
                del copy[key]
    else:
        copy = bpy.data.materials.new(name)
    if txn is not None:
        txn.add(lambda: _remove_material(copy), f"remove material {name}")
    try:  # a half-built copy must not stay behind
        copy.name = name
        if copy.node_tree is None:
            copy.use_nodes = True
        from_socket, constant = _base_color_source(copy) if source is not None else (None, DEFAULT_BASE_COLOR)
        emission = _constant_emission(copy) if source is not None else (0.0, 0.0, 0.0)
        _add_baked_lighting_nodes(copy.node_tree, image, from_socket, constant, emission)
        copy.use_fake_user = True
        tag_owner(copy, obj.name)
        copy[SLOT] = slot_index
        if source is not None:
            copy[SOURCE] = source
        copy[FINGERPRINT] = fingerprint(copy)
    except BaseException:
        _remove_material(copy)
        raise
    return copy


def _add_baked_lighting_nodes(tree, image, from_socket, constant, emission) -> None:
    """Replace the tree's outputs by ``light map x base colour (+ emission)`` through an Emission shader."""
    for node in [n for n in tree.nodes if n.type == "OUTPUT_MATERIAL"]:
        tree.nodes.remove(node)
    x, y = 1200.0, 600.0
    uv = tree.nodes.new("ShaderNodeUVMap")
    uv.uv_map = uvmaps.LIGHTMAP_UV
    uv.location = (x, y)
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = "Linear"
    tex.extension = "EXTEND"
    tex.location = (x + 200, y)
    tex.label = "PDIC light map"
    tree.links.new(uv.outputs["UV"], tex.inputs["Vector"])
    multiply = tree.nodes.new("ShaderNodeVectorMath")
    multiply.operation = "MULTIPLY"
    multiply.location = (x + 500, y)
    tree.links.new(tex.outputs["Color"], multiply.inputs[0])
    if from_socket is not None:
        tree.links.new(from_socket, multiply.inputs[1])
    else:
        multiply.inputs[1].default_value = constant
    radiance = multiply.outputs[0]
    if any(c > 0 for c in emission):
        add = tree.nodes.new("ShaderNodeVectorMath")
        add.operation = "ADD"
        add.location = (x + 700, y)
        tree.links.new(radiance, add.inputs[0])
        add.inputs[1].default_value = emission
        radiance = add.outputs[0]
    shader = tree.nodes.new("ShaderNodeEmission")
    shader.location = (x + 900, y)
    shader.inputs["Strength"].default_value = 1.0
    tree.links.new(radiance, shader.inputs["Color"])
    output = tree.nodes.new("ShaderNodeOutputMaterial")
    output.target = "ALL"
    output.location = (x + 1100, y)
    output.is_active_output = True
    tree.links.new(shader.outputs["Emission"], output.inputs["Surface"])
    for n in (uv, tex, multiply, shader, output):
        n["pdic"] = True


def build_copies(obj, image, txn, temporary: bool = False) -> tuple[list, list[str]]:
    """Build (not assign) a PDIC copy per material slot of ``obj``; returns (copies by slot, warnings)."""
    warnings = []
    if len(obj.material_slots) == 0:
        warnings.append(f"{obj.name}: has no material slots, so its light map is written but not shown "
                        f"in the viewport (add a material to see it)")
        return [], warnings
    copies = []
    for i, slot in enumerate(obj.material_slots):
        source = slot.material
        base = source.name if source is not None else f"Slot{i}"
        name = copy_name(base, obj.name) + (TEMPORARY_SUFFIX if temporary else "")
        copies.append(build_copy(obj, i, source, image, name, txn))
    return copies, warnings


TEMPORARY_SUFFIX = ".pdic_new"
"""A re-bake's new datablocks carry this until the commit gives them their final names."""


def _remove_material(material):
    if material is not None and material.name in bpy.data.materials and bpy.data.materials[material.name] == material:
        bpy.data.materials.remove(material)


# --------------------------------------------------------------------------- slots
def assign_copies(obj, copies: list, txn=None) -> None:
    """Show the baked lighting: each slot OBJECT-linked to its copy, remembering the user's link."""
    for i, copy in enumerate(copies):
        if _shows_copy(obj, i) == copy:
            continue
        if txn is not None:  # registered first: a failure half-way still restores the slot
            slot = obj.material_slots[i]
            txn.add(lambda obj=obj, i=i, link=slot.link, user=_object_material(slot): _set_slot(obj, i, link, user),
                    f"restore slot {i} of {obj.name}")
        assign_copy(obj, i, copy)


def assign_copy(obj, index: int, copy) -> None:
    """OBJECT-link slot ``index`` of ``obj`` to ``copy``; the copy records the slot's previous state."""
    slot = obj.material_slots[index]
    copy[USER_LINK] = slot.link
    user_material = _object_material(slot)
    if user_material is not None:
        copy[USER_OBJECT_MATERIAL] = user_material
    elif USER_OBJECT_MATERIAL in copy:
        del copy[USER_OBJECT_MATERIAL]
    slot.link = "OBJECT"
    slot.material = copy


def _restore_slot(obj, index: int, copy) -> None:
    """Put the slot back as the user had it (link and object-level material)."""
    _set_slot(obj, index, copy.get(USER_LINK, "DATA"), copy.get(USER_OBJECT_MATERIAL))


def _set_slot(obj, index: int, link: str, object_material) -> None:
    slot = obj.material_slots[index]
    slot.link = "OBJECT"
    slot.material = object_material
    slot.link = link


def _shows_copy(obj, index: int):
    """The PDIC copy slot ``index`` of ``obj`` shows, or None."""
    slot = obj.material_slots[index]
    if slot.link == "OBJECT" and is_pdic(slot.material):
        return slot.material
    return None


def release_mesh_copies(txn=None, meshes=None) -> int:
    """Put the user's material back wherever a PDIC copy became a mesh's own material.

    Joining objects (Ctrl+J) or copying materials turns the OBJECT-linked copies into
    mesh materials; each copy remembers its source (the user's material, or an empty
    slot). Returns the number of slots repaired; ``txn`` records how to undo them.
    """
    repaired = 0
    for mesh in (bpy.data.meshes if meshes is None else meshes):
        if mesh.library is not None:
            continue
        for i, material in enumerate(mesh.materials):
            if is_pdic(material):
                mesh.materials[i] = material.get(SOURCE)
                repaired += 1
                if txn is not None:
                    txn.add(lambda mesh=mesh, i=i, m=material: mesh.materials.__setitem__(i, m),
                            f"restore material {i} of mesh {mesh.name}")
    return repaired


def _release_copy(copy, txn=None) -> None:
    """Restore every slot (any object) and mesh material showing ``copy``."""
    for holder in bpy.data.objects:
        for i in range(len(holder.material_slots)):
            if _shows_copy(holder, i) == copy:
                _restore_slot(holder, i, copy)
                if txn is not None:
                    txn.add(lambda h=holder, i=i: assign_copy(h, i, copy), f"show {copy.name} on {holder.name}")
    release_mesh_copies(txn, [m for m in bpy.data.meshes if copy in m.materials[:]])


def _objects_of(scene_or_objects) -> list:
    if scene_or_objects is None:
        return list(bpy.data.objects)
    if isinstance(scene_or_objects, bpy.types.Scene):
        return list(scene_or_objects.objects)
    return list(scene_or_objects)


def set_shading(scene_or_objects, baked: bool) -> int:
    """Switch objects between baked lighting (True) and their original shading; returns slots switched."""
    switched = 0
    for obj in _objects_of(scene_or_objects):
        copies = {int(m[SLOT]): m for m in owned_materials(obj)}
        for i in range(len(obj.material_slots)):
            shown = _shows_copy(obj, i)
            if baked and shown is None and i in copies:
                assign_copy(obj, i, copies[i])
                switched += 1
            elif not baked and shown is not None:
                _restore_slot(obj, i, shown)
                switched += 1
    return switched


def is_baked_shading(obj) -> bool:
    return any(_shows_copy(obj, i) is not None for i in range(len(obj.material_slots)))


# --------------------------------------------------------------------------- removing
def keep_edited(copy, name: str | None = None) -> str:
    """Turn an edited copy into a plain material of the user's (tags dropped, ``<name> (edited)``)."""
    for key in (OWNER, OWNER_OBJECT, SLOT, SOURCE, USER_LINK, USER_OBJECT_MATERIAL, FINGERPRINT):
        if key in copy:
            del copy[key]
    copy.name = (name or copy.name) + EDITED_SUFFIX
    return copy.name


def _edited_message(copy) -> str:
    source = copy.get(SOURCE)
    where = f"material {source.name!r}" if source is not None else "the object's material"
    return (f"material {copy.name!r} (the baked-lighting copy) was edited after its bake; a bake rebuilds "
            f"it from {where}, so the edits are kept in material {copy.name + EDITED_SUFFIX!r}: "
            f"make them in {where} to keep them in future bakes")


def retire_outputs(owner, keep, txn, warnings: list) -> None:
    """Take ``owner``'s previous copies and image out of use, undoably: slots are restored
    and the datablocks renamed aside at once; ``txn.commit()`` deletes them (an edited
    copy is kept as a plain material, with a warning)."""
    for copy in [m for m in owned_materials(owner) if m not in keep]:
        _release_copy(copy, txn)
        if is_edited(copy):
            warnings.append(_edited_message(copy))
            _set_aside(copy, txn, on_commit=keep_edited)
        else:
            _set_aside(copy, txn, on_commit=lambda m, _: _remove_material(m))
    for image in [i for i in owned_images(owner) if i not in keep]:
        _set_aside(image, txn, on_commit=lambda i, _: _remove_image(i))


def _set_aside(idblock, txn, on_commit) -> None:
    """Free ``idblock``'s name for its replacement; ``on_commit(idblock, original_name)`` runs at commit."""
    name = idblock.name
    idblock.name = name[:40] + ".pdic_old"
    txn.add(lambda: setattr(idblock, "name", name), f"name {name} back", commit=lambda: on_commit(idblock, name))


def rename(idblock, name: str, txn) -> None:
    """Give ``idblock`` its final ``name`` (undo: its current one)."""
    old = idblock.name
    idblock.name = name
    txn.add(lambda: setattr(idblock, "name", old), f"name {name} back to {old}")


def remove_outputs(owner, keep=()) -> int:
    """Remove the PDIC copies and image of one object (restoring its slots); returns datablocks removed.

    owner : the object or its name. keep : datablocks not to remove.
    An edited copy is kept as a plain material (see :func:`keep_edited`).
    """
    removed = 0
    for copy in owned_materials(owner):
        if copy not in keep:
            removed += _drop_copy(copy)
    for image in owned_images(owner):
        if image not in keep:
            bpy.data.images.remove(image)
            removed += 1
    return removed


def _drop_copy(copy) -> int:
    """Release and delete ``copy``, or keep it as a plain material if edited; returns 1 if deleted."""
    _release_copy(copy)
    if is_edited(copy):
        keep_edited(copy)
        return 0
    bpy.data.materials.remove(copy)
    return 1


def clear(scene_or_objects=None) -> dict:
    """Remove every PDIC-owned thing from the file and restore slots exactly.

    scene_or_objects : a Scene (its objects), a list of objects, or None (the whole file).
    Restores material slots and mesh materials (also after Join), removes material
    copies, light-map images and the PDIC_Lightmap UV maps; an edited copy is kept as a
    plain material (``kept_edited``). Files on disk are kept. Returns counts per kind.
    """
    objects = _objects_of(scene_or_objects)
    whole = scene_or_objects is None
    counts = {"materials": 0, "images": 0, "uv_maps": 0, "kept_edited": 0}
    for obj in objects:  # restore slots showing a copy, on any object (even a renamed one)
        for i in range(len(obj.material_slots)):
            shown = _shows_copy(obj, i)
            if shown is not None:
                _restore_slot(obj, i, shown)
    meshes = ([m for m in bpy.data.meshes if m.library is None] if whole else
              list({o.data for o in objects if o.type == "MESH" and o.data is not None and o.data.library is None}))
    release_mesh_copies(meshes=meshes)
    for copy in [m for m in owned_materials() if whole or any(_owned_by(m, o) for o in objects)]:
        deleted = _drop_copy(copy)
        counts["materials"] += deleted
        counts["kept_edited"] += 1 - deleted
    for image in [i for i in owned_images() if whole or any(_owned_by(i, o) for o in objects)]:
        bpy.data.images.remove(image)
        counts["images"] += 1
    for mesh in meshes:
        if uvmaps.remove_lightmap_uv(mesh):
            counts["uv_maps"] += 1
    return counts
