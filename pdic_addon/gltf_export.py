"""Export the baked scene as ``.glb`` with its light maps, for three.js, engines and viewers.

Blender's own glTF exporter (``io_scene_gltf2``, shipped with Blender and the bpy
wheel) writes everything it already knows: meshes with every UV map, the user's
ORIGINAL materials (PDIC's emission copies are swapped out for the export and
back in afterwards), their textures, the cameras. This module adds only the
light-map part, by post-processing the .glb:

* **UVs**: the ``PDIC_Lightmap`` UV map is ``TEXCOORD_1`` of every baked primitive
  (swapped with whatever the exporter put there; a mesh whose only UV map is the
  light map's gets it as ``TEXCOORD_0`` and ``TEXCOORD_1``).
* **Images**: each light-map image (one per object, or one per atlas) as an 8-bit
  **RGBM** PNG appended to the BIN chunk: ``linear = rgb * a * range`` with
  ``rgb``, ``a`` in [0, 1] (PNG bytes / 255, no sRGB transfer, alpha NOT
  premultiplied) and ``range`` a power of two >= the image's largest value. The
  values are what PDIC bakes: irradiance / pi (Blender's light units), so outgoing
  radiance = base colour x decoded value. Relative quantisation error <= 0.2 % of
  a texel's brightest channel above ``range / 255``.
* **Binding**: each baked primitive's material is a copy of the user's material with
  ``extensions.MOZ_lightmap = {"index": texture, "texCoord": 1, "intensity": 1}``
  (the extension Mozilla Hubs reads) and ``extras.pdic_lightmap = {"encoding":
  "RGBM", "range": R, "texCoord": 1, "units": "irradiance/pi"}``; the root's
  ``extras.pdic`` lists the light maps (name, image index, range) and the world's
  background radiance. A reader that ignores ``extras`` and decodes the texture
  as plain colour is wrong by the RGBM factor: ``web/`` shows how to decode.
"""
from __future__ import annotations

import copy as copy_module
import json
import math
import os
import struct
import tempfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np
from bpy_extras.io_utils import ExportHelper

from . import uvmaps

GLB_MAGIC, GLB_JSON, GLB_BIN = 0x46546C67, 0x4E4F534A, 0x004E4942
EXTENSION = "MOZ_lightmap"
LIGHTMAP_TEXCOORD = 1
LINEAR, CLAMP_TO_EDGE = 9729, 33071


class ExportError(ValueError):
    """The scene cannot be exported; the message names the object, image or path."""


# --------------------------------------------------------------------------- RGBM (pure)
def rgbm_range(rgb: np.ndarray) -> float:
    """Smallest power of two >= the largest value (at least 1): the RGBM ``range``."""
    peak = float(np.max(rgb, initial=0.0))
    if not math.isfinite(peak):
        raise ExportError("light map has NaN or infinite texels")
    return float(2.0 ** max(0, math.ceil(math.log2(peak)))) if peak > 1.0 else 1.0


def encode_rgbm(rgb: np.ndarray, value_range: float) -> np.ndarray:
    """(H, W, 3) float linear >= 0 -> (H, W, 4) uint8 RGBM (``rgb * a * range`` decodes it)."""
    rgb = np.clip(np.asarray(rgb, np.float64), 0.0, value_range)
    m = np.ceil(rgb.max(axis=2) / value_range * 255.0)
    m = np.clip(m, 1.0, 255.0)  # a >= 1/255: black stays decodable
    scale = m[..., None] / 255.0 * value_range
    c = np.clip(np.round(rgb / scale * 255.0), 0, 255)
    return np.concatenate([c, m[..., None]], axis=2).astype(np.uint8)


def decode_rgbm(rgbm: np.ndarray, value_range: float) -> np.ndarray:
    """(H, W, 4) uint8 RGBM -> (H, W, 3) float32 linear."""
    x = np.asarray(rgbm, np.float64) / 255.0
    return (x[..., :3] * x[..., 3:4] * value_range).astype(np.float32)


def png_rgba(rgba: np.ndarray) -> bytes:
    """(H, W, 4) uint8, row 0 = top, as an 8-bit RGBA PNG (no gamma chunk: bytes are data)."""
    rgba = np.ascontiguousarray(rgba, np.uint8)
    h, w, _ = rgba.shape
    raw = np.concatenate([np.zeros((h, 1), np.uint8), rgba.reshape(h, w * 4)], axis=1).tobytes()

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 6, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))


# --------------------------------------------------------------------------- GLB container (pure)
def read_glb(data: bytes) -> tuple[dict, bytes]:
    """(JSON document, BIN chunk) of a .glb (glTF 2.0 binary container)."""
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != GLB_MAGIC or version != 2 or length != len(data):
        raise ExportError(f"not a glTF 2.0 binary (magic {magic:#x}, version {version}, length {length}/{len(data)})")
    doc, binary, offset = None, b"", 12
    while offset < length:
        size, kind = struct.unpack_from("<II", data, offset)
        body = data[offset + 8:offset + 8 + size]
        if kind == GLB_JSON:
            doc = json.loads(body.decode("utf-8"))
        elif kind == GLB_BIN:
            binary = bytes(body)
        offset += 8 + size
    if doc is None:
        raise ExportError("the .glb has no JSON chunk")
    return doc, binary


def write_glb(doc: dict, binary: bytes) -> bytes:
    """A .glb from a JSON document and its BIN chunk (both padded to 4 bytes)."""
    text = json.dumps(doc, separators=(",", ":"), allow_nan=False).encode("utf-8")
    text += b" " * (-len(text) % 4)
    binary = bytes(binary) + b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<II", len(text), GLB_JSON) + text
    if binary:
        chunks += struct.pack("<II", len(binary), GLB_BIN) + binary
    return struct.pack("<III", GLB_MAGIC, 2, 12 + len(chunks)) + chunks


# --------------------------------------------------------------------------- light-map part (pure)
@dataclass(frozen=True)
class LightmapImage:
    """One light map to embed: ``name``, (H, W, 3) float linear ``rgb`` (row 0 = bottom, v = 0)."""

    name: str
    rgb: np.ndarray


@dataclass(frozen=True)
class Binding:
    """A baked object: glTF node ``node`` (its name), light map ``image`` (index into the images),
    and the index of ``PDIC_Lightmap`` among its mesh's UV maps (= the exporter's TEXCOORD_n)."""

    node: str
    image: int
    uv_index: int


def add_lightmaps(doc: dict, binary: bytes, images: list, bindings: list, background=(0.0, 0.0, 0.0)):
    """Embed ``images`` (list of :class:`LightmapImage`) as RGBM PNGs and bind them per node.

    Returns (new document, new BIN chunk). The input document is not modified.
    """
    doc = copy_module.deepcopy(doc)
    binary = bytearray(binary)
    textures, ranges = [], []
    for image in images:
        value_range = rgbm_range(image.rgb)
        png = png_rgba(encode_rgbm(image.rgb, value_range)[::-1])  # glTF images: row 0 = top (v = 1)
        binary += b"\0" * (-len(binary) % 4)
        doc.setdefault("bufferViews", []).append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(png)})
        binary += png
        doc.setdefault("images", []).append({"bufferView": len(doc["bufferViews"]) - 1, "mimeType": "image/png",
                                             "name": image.name})
        doc.setdefault("samplers", []).append({"magFilter": LINEAR, "minFilter": LINEAR,
                                               "wrapS": CLAMP_TO_EDGE, "wrapT": CLAMP_TO_EDGE})
        doc.setdefault("textures", []).append({"sampler": len(doc["samplers"]) - 1,
                                               "source": len(doc["images"]) - 1})
        textures.append(len(doc["textures"]) - 1)
        ranges.append(value_range)
    if not doc.get("buffers"):
        doc["buffers"] = [{}]
    doc["buffers"][0]["byteLength"] = len(binary)
    _bind(doc, bindings, textures, ranges)
    doc["extensionsUsed"] = sorted(set(doc.get("extensionsUsed", [])) | {EXTENSION})
    doc.setdefault("extras", {})["pdic"] = {
        "encoding": "RGBM", "units": "irradiance/pi", "texCoord": LIGHTMAP_TEXCOORD,
        "lightmaps": [{"name": im.name, "texture": t, "range": r} for im, t, r in zip(images, textures, ranges)],
        "background": [float(c) for c in background]}
    return doc, bytes(binary)


def _bind(doc: dict, bindings: list, textures: list, ranges: list) -> None:
    """Point each bound node's primitives at TEXCOORD_1 = light-map UVs and a material with the light map."""
    nodes = {n.get("name"): i for i, n in enumerate(doc.get("nodes", []))}
    mesh_owner: dict = {}
    materials: dict = {}
    for b in bindings:
        if b.node not in nodes or "mesh" not in doc["nodes"][nodes[b.node]]:
            raise ExportError(f"object {b.node!r} is not in the exported glTF as a mesh node")
        node = doc["nodes"][nodes[b.node]]
        mesh_index = node["mesh"]
        if mesh_owner.setdefault(mesh_index, b.image) != b.image:  # shared mesh, other light map
            doc["meshes"].append(copy_module.deepcopy(doc["meshes"][mesh_index]))
            mesh_index = node["mesh"] = len(doc["meshes"]) - 1
            mesh_owner[mesh_index] = b.image
        for prim in doc["meshes"][mesh_index]["primitives"]:
            swap = _move_uv(prim["attributes"], b.uv_index, b.node)
            key = (prim.get("material"), b.image, swap)
            if key not in materials:
                materials[key] = _lightmap_material(doc, prim.get("material"), textures[b.image],
                                                    ranges[b.image], swap)
            prim["material"] = materials[key]


def _move_uv(attributes: dict, k: int, node: str):
    """Make TEXCOORD_1 the light map's; returns the pair of sets swapped (or None)."""
    name = f"TEXCOORD_{k}"
    if name not in attributes:
        raise ExportError(f"object {node!r}: the exporter wrote no {name} for UV map {uvmaps.LIGHTMAP_UV}")
    if k == LIGHTMAP_TEXCOORD:
        return None
    if k == 0 and "TEXCOORD_1" not in attributes:  # the light map is the mesh's only UV map
        attributes["TEXCOORD_1"] = attributes["TEXCOORD_0"]
        return None
    attributes[name], attributes["TEXCOORD_1"] = attributes["TEXCOORD_1"], attributes[name]
    return (1, k)


def _lightmap_material(doc: dict, source, texture: int, value_range: float, swap) -> int:
    """A copy of material ``source`` (None: glTF's default) carrying the light map; returns its index."""
    base = copy_module.deepcopy(doc["materials"][source]) if source is not None else {"name": "default"}
    if swap is not None:
        _swap_texcoords(base, *swap)
    base.setdefault("extensions", {})[EXTENSION] = {"index": texture, "texCoord": LIGHTMAP_TEXCOORD,
                                                    "intensity": 1.0}
    base.setdefault("extras", {})["pdic_lightmap"] = {"encoding": "RGBM", "range": value_range,
                                                      "texCoord": LIGHTMAP_TEXCOORD, "units": "irradiance/pi"}
    doc.setdefault("materials", []).append(base)
    return len(doc["materials"]) - 1


def _swap_texcoords(value, a: int, b: int) -> None:
    """Swap texCoord a <-> b in every textureInfo (a dict with an integer ``index``) of a material."""
    if isinstance(value, dict):
        if isinstance(value.get("index"), int):
            t = value.get("texCoord", 0)
            if t in (a, b):
                value["texCoord"] = b if t == a else a
        for v in value.values():
            _swap_texcoords(v, a, b)
    elif isinstance(value, list):
        for v in value:
            _swap_texcoords(v, a, b)


# --------------------------------------------------------------------------- Blender side
def baked_objects(scene) -> list:
    """(object, light-map image) of every object in ``scene`` with PDIC light-map outputs."""
    from . import writeback

    found = []
    for obj in scene.objects:
        if obj.type != "MESH":
            continue
        image = None
        for material in writeback.owned_materials(obj.name):
            for node in material.node_tree.nodes if material.node_tree else ():
                if node.type == "TEX_IMAGE" and node.get("pdic") and node.image is not None:
                    image = node.image
        if image is not None and uvmaps.LIGHTMAP_UV in obj.data.uv_layers:
            found.append((obj, image))
    return found


def _image_rgb(image) -> np.ndarray:
    w, h = image.size
    pixels = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(pixels)
    rgb = pixels.reshape(h, w, 4)[..., :3]
    if not np.isfinite(rgb).all():
        raise ExportError(f"light-map image {image.name!r} has NaN or infinite texels")
    return rgb


def world_background(scene) -> tuple:
    """The world's uniform radiance (linear RGB), read as the bake reads it (what PDIC's camera render shows)."""
    from .extract_lights import extract_world

    return tuple(float(c) for c in extract_world(scene.world, []).radiance)


def export_glb(context, path) -> Path:
    """Export ``context.scene`` as ``path`` (.glb) with light maps; returns the path.

    Raises ExportError naming the problem when nothing is baked or the path cannot be
    written; the scene's shading (original or baked) is the same afterwards.
    """
    from . import writeback

    path = Path(bpy.path.abspath(str(path))).resolve()
    if path.suffix.lower() != ".glb":
        raise ExportError(f"export path {str(path)!r} must end in .glb")
    if not path.parent.is_dir():
        raise ExportError(f"export folder {str(path.parent)!r} does not exist")
    pairs = baked_objects(context.scene)
    if not pairs:
        raise ExportError("nothing to export: no object of this scene has a PDIC light map (bake first)")
    images, index = [], {}
    for _, image in pairs:
        if image.name not in index:
            index[image.name] = len(images)
            images.append(LightmapImage(image.name, _image_rgb(image)))
    bindings = [Binding(obj.name, index[image.name], obj.data.uv_layers.find(uvmaps.LIGHTMAP_UV))
                for obj, image in pairs]
    showing = [obj for obj, _ in pairs if writeback.is_baked_shading(obj)]
    fd, raw = tempfile.mkstemp(suffix=".glb", dir=path.parent, prefix=".pdic_export-")
    os.close(fd)
    try:
        writeback.set_shading(showing, baked=False)  # the user's materials go into the file
        try:
            result = bpy.ops.export_scene.gltf(filepath=raw, export_format="GLB", export_texcoords=True,
                                               export_normals=True, export_cameras=True, export_lights=False,
                                               export_materials="EXPORT", export_image_format="AUTO",
                                               use_selection=False, export_extras=False)
        finally:
            writeback.set_shading(showing, baked=True)
        if "FINISHED" not in result:
            raise ExportError(f"Blender's glTF exporter did not finish ({', '.join(result)})")
        doc, binary = read_glb(Path(raw).read_bytes())
        doc, binary = add_lightmaps(doc, binary, images, bindings, world_background(context.scene))
        Path(raw).write_bytes(write_glb(doc, binary))
        os.replace(raw, path)
    except OSError as e:
        raise ExportError(f"cannot write {str(path)!r}: {e.strerror or e}") from e
    finally:
        if os.path.exists(raw):
            os.unlink(raw)
    return path


# --------------------------------------------------------------------------- operator
class PDIC_OT_export_glb(bpy.types.Operator, ExportHelper):
    """Export the baked scene as .glb with its light maps (original materials, light maps on TEXCOORD_1)"""

    bl_idname = "pdic.export_glb"
    bl_label = "Export glTF with Light Maps"
    filename_ext = ".glb"
    filter_glob: bpy.props.StringProperty(default="*.glb", options={"HIDDEN"})

    def execute(self, context):
        try:
            path = export_glb(context, self.filepath)
        except ExportError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.report({"INFO"}, f"PDIC: exported {path}")
        return {"FINISHED"}


classes = (PDIC_OT_export_glb,)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
