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

import os
import uuid
from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np

from . import uvmaps

OWNER = "pdic_owner"           # ID property: name of the object a PDIC datablock belongs to
SLOT = "pdic_slot"             # material copies: slot index
SOURCE = "pdic_source"         # material copies: the user's material (ID pointer; absent for an empty slot)
USER_LINK = "pdic_user_link"   # material copies: the slot's link before the bake, 'DATA' or 'OBJECT'
USER_OBJECT_MATERIAL = "pdic_user_object_material"  # the object-level material before the bake (ID pointer)
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
    """Write ``path`` with ``write(path)``, backing up an existing file for undo (commit drops the backup)."""
    backup = None
    if path.exists():
        backup = path.with_name(path.name + f".pdic-backup-{uuid.uuid4().hex[:8]}")
        os.replace(path, backup)

    def undo():
        if path.exists():
            path.unlink()
        if backup is not None and backup.exists():
            os.replace(backup, path)

    def commit():
        if backup is not None and backup.exists():
            backup.unlink()

    txn.add(undo, f"restore file {path}", commit=commit)
    try:
        write(path)
    except (OSError, RuntimeError) as e:
        raise WritebackError(f"cannot write {str(path)!r}: {e}") from e
    if not path.exists():
        raise WritebackError(f"cannot write {str(path)!r}: Blender did not create it")


# --------------------------------------------------------------------------- images
def image_name(object_name: str) -> str:
    return IMAGE_PREFIX + object_name


def image_filename(object_name: str) -> str:
    return bpy.path.clean_name(image_name(object_name)) + ".exr"


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
    image[OWNER] = object_name
    return image, relpath


# --------------------------------------------------------------------------- material copies
def copy_name(material_name: str, object_name: str) -> str:
    return f"{material_name}{COPY_INFIX}{object_name}"


def is_pdic(idblock) -> bool:
    return idblock is not None and OWNER in idblock.keys()


def _object_material(slot):
    """The slot's object-level material, whatever the slot's link (restores the link)."""
    if slot.link == "OBJECT":
        return slot.material
    slot.link = "OBJECT"
    material = slot.material
    slot.link = "DATA"
    return material


def _base_color_source(material):
    """(from_socket or None, constant rgb) feeding the base colour of ``material``'s surface."""
    fallback = tuple(material.diffuse_color[:3]) if material is not None else DEFAULT_BASE_COLOR
    if material is None or material.node_tree is None:
        return None, fallback
    tree = material.node_tree
    outputs = [n for n in tree.nodes if n.type == "OUTPUT_MATERIAL" and n.target in ("ALL", "EEVEE")]
    output = next((n for n in outputs if n.is_active_output), outputs[0] if outputs else None)
    if output is None or not output.inputs["Surface"].is_linked:
        return None, fallback
    node = output.inputs["Surface"].links[0].from_node
    while node.type == "REROUTE" and node.inputs[0].is_linked:
        node = node.inputs[0].links[0].from_node
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
    if material is None or material.node_tree is None:
        return zero
    for node in material.node_tree.nodes:
        if node.type == "BSDF_PRINCIPLED":
            color, strength = node.inputs["Emission Color"], node.inputs["Emission Strength"]
        else:
            continue
        if color.is_linked or strength.is_linked:
            return zero
        return tuple(float(c) * float(strength.default_value) for c in color.default_value[:3])
    return zero


def build_copy(obj, slot_index: int, source, image, name: str):
    """A new material showing ``light map x base colour`` of ``source`` (None = empty slot).

    Tree: UV Map (PDIC_Lightmap) -> Image Texture (light map, Non-Color) ->
    Vector Math MULTIPLY with the source's base colour (its linked socket or
    constant) [-> ADD constant emission] -> Emission (strength 1) -> Material Output.
    """
    if source is not None:
        copy = source.copy()
        for key in list(copy.keys()):  # do not inherit the user's custom properties' PDIC tags
            if key.startswith("pdic_"):
                del copy[key]
    else:
        copy = bpy.data.materials.new(name)
    copy.name = name
    if copy.node_tree is None:
        copy.use_nodes = True
    tree = copy.node_tree
    from_socket, constant = _base_color_source(copy) if source is not None else (None, DEFAULT_BASE_COLOR)
    emission = _constant_emission(copy) if source is not None else (0.0, 0.0, 0.0)
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

    copy.use_fake_user = True
    copy[OWNER] = obj.name
    copy[SLOT] = slot_index
    if source is not None:
        copy[SOURCE] = source
    return copy


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
        name = copy_name(base, obj.name) + (".pdic_new" if temporary else "")
        copy = build_copy(obj, i, source, image, name)
        txn.add(lambda copy=copy: _remove_material(copy), f"remove material {name}")
        copies.append(copy)
    return copies, warnings


def _remove_material(material):
    if material is not None and material.name in bpy.data.materials and bpy.data.materials[material.name] == material:
        bpy.data.materials.remove(material)


# --------------------------------------------------------------------------- slots
def assign_copies(obj, copies: list, txn=None) -> None:
    """Show the baked lighting: each slot OBJECT-linked to its copy, remembering the user's link."""
    for i, copy in enumerate(copies):
        if _shows_copy(obj, i) == copy:
            continue
        assign_copy(obj, i, copy)
        if txn is not None:
            txn.add(lambda obj=obj, i=i, copy=copy: _restore_slot(obj, i, copy), f"restore slot {i} of {obj.name}")


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
    slot = obj.material_slots[index]
    slot.link = "OBJECT"
    slot.material = copy.get(USER_OBJECT_MATERIAL)
    slot.link = copy.get(USER_LINK, "DATA")


def _shows_copy(obj, index: int):
    """The PDIC copy slot ``index`` of ``obj`` shows, or None."""
    slot = obj.material_slots[index]
    if slot.link == "OBJECT" and is_pdic(slot.material):
        return slot.material
    return None


def owned_materials(object_name: str | None = None) -> list:
    return [m for m in bpy.data.materials if is_pdic(m) and (object_name is None or m[OWNER] == object_name)]


def owned_images(object_name: str | None = None) -> list:
    return [i for i in bpy.data.images if is_pdic(i) and (object_name is None or i[OWNER] == object_name)]


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
        copies = {int(m[SLOT]): m for m in owned_materials(obj.name)}
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
def remove_outputs(object_name: str, keep=()) -> int:
    """Remove the PDIC copies and image of one object (restoring its slots); returns datablocks removed.

    keep : datablocks not to remove (a re-bake's new outputs).
    """
    removed = 0
    obj = bpy.data.objects.get(object_name)
    for copy in owned_materials(object_name):
        if copy in keep:
            continue
        holders = [obj] if obj is not None else []
        holders += [o for o in bpy.data.objects if o is not obj and any(
            s.link == "OBJECT" and s.material == copy for s in o.material_slots)]
        for holder in holders:
            for i in range(len(holder.material_slots)):
                if _shows_copy(holder, i) == copy:
                    _restore_slot(holder, i, copy)
        bpy.data.materials.remove(copy)
        removed += 1
    for image in owned_images(object_name):
        if image in keep:
            continue
        bpy.data.images.remove(image)
        removed += 1
    return removed


def clear(scene_or_objects=None) -> dict:
    """Remove every PDIC-owned thing from the file and restore slots exactly.

    scene_or_objects : a Scene (its objects), a list of objects, or None (the whole file).
    Restores material slots, removes material copies, light-map images and the
    PDIC_Lightmap UV maps. Files on disk are kept. Returns counts per kind.
    """
    objects = _objects_of(scene_or_objects)
    whole = scene_or_objects is None
    counts = {"materials": 0, "images": 0, "uv_maps": 0}
    # restore slots showing a copy, on any object (even a renamed one)
    for obj in objects:
        for i in range(len(obj.material_slots)):
            shown = _shows_copy(obj, i)
            if shown is not None:
                _restore_slot(obj, i, shown)
    names = {o.name for o in objects}
    for copy in owned_materials():
        if whole or copy[OWNER] in names:
            bpy.data.materials.remove(copy)
            counts["materials"] += 1
    for image in owned_images():
        if whole or image[OWNER] in names:
            bpy.data.images.remove(image)
            counts["images"] += 1
    if scene_or_objects is None:
        meshes = [m for m in bpy.data.meshes if m.library is None]
    else:
        meshes = {o.data for o in objects if o.type == "MESH" and o.data is not None and o.data.library is None}
    for mesh in meshes:
        if uvmaps.remove_lightmap_uv(mesh):
            counts["uv_maps"] += 1
    return counts
