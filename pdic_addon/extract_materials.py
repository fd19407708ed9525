"""Blender materials and images -> :class:`core.scene.Materials` and :class:`core.scene.Texture`.

What is understood (everything else falls back to a documented default with a
warning naming the material):

* the shader linked into the Surface of the Cycles material output is a
  Principled BSDF (Base Color; Emission Color x Emission Strength), a Diffuse
  BSDF (Color) or an Emission shader (Color x Strength; it reflects nothing);
* a colour input is either its constant ``default_value`` or an Image Texture
  node linked directly into it (its Color output), read once through
  ``Image.pixels.foreach_get``; reroute nodes in between are followed;
* what light passes (Cycles' transparent shadows, ``Geometry.transmission``):
  a Principled BSDF of Alpha a and Transmission Weight w passes
  tau = 1 - a (1 - w) of the light straight through and reflects diffusely
  a (1 - w) Base Color; its emission is a x Emission. A Transparent BSDF passes
  the mean of its Color. Glass counts as straight transmission: no refraction,
  no Fresnel reflection, no tint (measured against Cycles 5.0 under a point light
  3 m above: a glass cube leaves 0.91, a single glass sheet 0.67 of the unshadowed
  floor; PDIC leaves 1.0). Alpha or Transmission driven by a texture uses the constant.

Defaults: an unknown shader is :data:`DEFAULT_BASE_COLOR` grey with no
emission (Blender's default surface); an empty slot or an object without
materials gets the same grey; a Surface socket with nothing linked renders
black in Cycles and is extracted as black.
"""
from __future__ import annotations

import bpy
import numpy as np

from ..core.scene import Materials, SceneError, Texture

# Before Blender 5.0 a material or world could switch its node tree off (use_nodes);
# 5.0 deprecates the flag (always on) and warns when it is read.
USE_NODES_FLAG = bpy.app.version < (5, 0, 0)

DEFAULT_BASE_COLOR = (0.8, 0.8, 0.8)
"""Blender's default surface, base colour 0.8, no emission. Cycles shades it as a Principled BSDF,
whose specular layer is not modelled here (README, Known limitations)."""

# Colour spaces whose pixel values already are linear (or are data): passed through.
_LINEAR_COLORSPACES = {"Non-Color", "Linear", "Linear Rec.709", "Linear CIE-XYZ E", "Raw", "Generic Data"}


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer function decoded (IEC 61966-2-1), element-wise.

    Parameters
    ----------
    c : array of float32, sRGB-encoded values, typically in [0, 1].

    Returns
    -------
    Array of the same shape, float32, linear values (0.5 -> 0.2140).
    """
    c = np.asarray(c, dtype=np.float32)
    return np.where(c <= 0.04045, c / 12.92, ((np.maximum(c, 0.04045) + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _output_node(tree, node_type: str):
    """The output node Cycles uses: the active one targeting ALL/CYCLES, else the first such."""
    outputs = [n for n in tree.nodes if n.type == node_type and getattr(n, "target", "ALL") in ("ALL", "CYCLES")]
    for n in outputs:
        if n.is_active_output:
            return n
    return outputs[0] if outputs else None


def _linked_node(socket):
    """The node feeding ``socket`` (following reroutes and skipping muted links), or None."""
    while socket.is_linked:
        links = [l for l in socket.links if not l.is_muted]
        if not links:
            return None
        node = links[0].from_node
        if node.type != "REROUTE":
            return node, links[0].from_socket
        socket = node.inputs[0]
    return None


def _image_path(image) -> str:
    """The image's file path for messages: Blender's path, plus the absolute one when it is relative."""
    if image.source != "FILE" or not image.filepath:
        return "packed" if image.packed_file is not None else "generated"
    path = image.filepath
    try:
        absolute = bpy.path.abspath(path, library=image.library)
    except (TypeError, ValueError):
        absolute = path
    return path if absolute == path else f"{path} = {absolute}"


class MaterialTable:
    """One global, deduplicated table of materials and textures, filled while extracting.

    Use :meth:`index` for every material slot met, then :meth:`build`.
    ``warnings`` collects one message per problem, naming the material/image.
    """

    def __init__(self, warnings: list):
        self.warnings = warnings
        self._index: dict = {}            # material session_uid (or None for the default) -> row
        self._names: list = []
        self._base_color: list = []
        self._texture: list = []
        self._emission: list = []
        self._textures: list = []         # core.scene.Texture
        self._texture_index: dict = {}    # (image session_uid, interpolation) -> texture row
        self._uv_map: list = []           # per row: UV map named by the texture's UV Map node ("" = render map)
        self._transmission: list = []     # per row: tau, the fraction of light passing straight through
        self._pending_uv_map = ""

    # ------------------------------------------------------------------ public
    def index(self, material) -> int:
        """Row of ``material`` (a bpy Material, evaluated or not, or None for an empty slot)."""
        material = None if material is None else material.original
        key = None if material is None else material.session_uid
        if key not in self._index:
            self._pending_uv_map = ""
            if material is None:
                row = ("default", DEFAULT_BASE_COLOR, -1, (0.0, 0.0, 0.0), 0.0)
            else:
                row = self._read_material(material)
            self._index[key] = len(self._names)
            columns = (self._names, self._base_color, self._texture, self._emission, self._transmission)
            for column, value in zip(columns, row):
                column.append(value)
            self._uv_map.append(self._pending_uv_map)
        return self._index[key]

    def transmission_of(self, rows: np.ndarray) -> np.ndarray:
        """(t,) float32 tau in [0, 1] of material ``rows`` (t,): 0 opaque, 1 fully transparent."""
        return np.array(self._transmission, np.float32)[rows] if len(rows) else np.zeros(0, np.float32)

    def name_of(self, row: int) -> str:
        """Material name of ``row`` (for messages)."""
        return self._names[row]

    def uv_map_of(self, row: int) -> str:
        """UV map the material of ``row`` samples its texture with; "" for the active render UV map."""
        return self._uv_map[row]

    def build(self) -> tuple[Materials, tuple]:
        """(Materials, textures) for :class:`core.scene.Scene`; at least the default material."""
        if not self._names:
            self.index(None)
        return (
            Materials(
                names=tuple(self._names),
                base_color=np.array(self._base_color, np.float32).reshape(-1, 3),
                texture=np.array(self._texture, np.int32),
                emission=np.array(self._emission, np.float32).reshape(-1, 3),
            ),
            tuple(self._textures),
        )

    # ------------------------------------------------------------------ reading
    def _warn(self, message: str):
        self.warnings.append(message)

    def _read_material(self, mat):
        """(name, base_color, texture, emission, transmission tau) of one material."""
        name = mat.name
        black = (0.0, 0.0, 0.0)
        tree = mat.node_tree
        if tree is None or (USE_NODES_FLAG and not mat.use_nodes):
            # Cycles renders a node-less material as a diffuse BSDF of its viewport colour.
            return name, tuple(mat.diffuse_color[:3]), -1, black, 0.0
        out = _output_node(tree, "OUTPUT_MATERIAL")
        if out is None:
            self._warn(f"material {name!r}: no material output node; using default grey {DEFAULT_BASE_COLOR[0]}")
            return name, DEFAULT_BASE_COLOR, -1, black, 0.0
        fed = _linked_node(out.inputs["Surface"])
        if fed is None:
            self._warn(f"material {name!r}: nothing connected to the Surface output; it renders black")
            return name, black, -1, black, 0.0
        node = fed[0]
        if node.type == "BSDF_PRINCIPLED":
            return self._principled(node, name)
        if node.type == "BSDF_DIFFUSE":
            base, tex = self._color(node.inputs["Color"], name, "Color")
            return name, base, tex, black, 0.0
        if node.type == "EMISSION":
            emission = self._emitted(node.inputs["Color"], node.inputs["Strength"], name)
            return name, black, -1, emission, 0.0
        if node.type == "BSDF_TRANSPARENT":
            color = self._constant(node.inputs["Color"], name, "Color")
            return name, black, -1, black, float(np.clip(np.mean(color), 0.0, 1.0))
        self._warn(
            f"material {name!r}: unsupported shader node {node.name!r} ({node.bl_idname}) on the Surface output; "
            f"using default grey {DEFAULT_BASE_COLOR[0]}, no emission"
        )
        return name, DEFAULT_BASE_COLOR, -1, black, 0.0

    def _principled(self, node, name: str):
        """(name, base_color, texture, emission, tau) of a Principled BSDF: Alpha and Transmission pass light."""
        base, tex = self._color(node.inputs["Base Color"], name, "Base Color")
        emission = self._emitted(node.inputs["Emission Color"], node.inputs["Emission Strength"], name)
        alpha = float(np.clip(self._constant(node.inputs["Alpha"], name, "Alpha"), 0.0, 1.0))
        weight = float(np.clip(self._constant(node.inputs["Transmission Weight"], name, "Transmission Weight"), 0.0, 1.0))
        diffuse = alpha * (1.0 - weight)
        base = tuple(c * diffuse for c in base)
        if tex >= 0 and diffuse < 1.0:
            self._warn(f"material {name!r}: Alpha/Transmission scale a textured Base Color, which is not "
                       f"supported; its reflection is the texture's, unscaled")
        return name, base, tex, tuple(c * alpha for c in emission), 1.0 - diffuse

    def _constant(self, socket, name: str, what: str):
        """The socket's default value (rgb tuple or float), warning if something is linked into it."""
        if _linked_node(socket) is not None:
            node = _linked_node(socket)[0]
            self._warn(f"material {name!r}: {what} is driven by an unsupported node {node.name!r} ({node.bl_idname}); using its constant value")
        value = socket.default_value
        return tuple(value[:3]) if hasattr(value, "__len__") else float(value)

    def _color(self, socket, name: str, what: str):
        """(constant rgb, texture row or -1) of a colour input."""
        constant = tuple(socket.default_value[:3])
        fed = _linked_node(socket)
        if fed is None:
            return constant, -1
        node, from_socket = fed
        if node.type != "TEX_IMAGE" or from_socket.name != "Color":
            self._warn(f"material {name!r}: {what} is driven by an unsupported node {node.name!r} ({node.bl_idname}); using its constant colour")
            return constant, -1
        return constant, self._texture_row(node, name)

    def _emitted(self, color_socket, strength_socket, name: str):
        """Emitted radiance (rgb) = Emission Color x Emission Strength, constants only; negative -> 0, warned."""
        color = self._constant(color_socket, name, color_socket.name)
        strength = self._constant(strength_socket, name, strength_socket.name)
        radiance = tuple(float(c) * strength for c in color)
        if min(radiance) < 0:
            self._warn(f"material {name!r}: negative emission ({strength_socket.name} {strength:g} x "
                       f"{color_socket.name} {tuple(round(float(c), 4) for c in color)}) is not supported "
                       "(light cannot be subtracted); its negative channels emit nothing")
            radiance = tuple(max(c, 0.0) for c in radiance)
        return radiance

    def _texture_row(self, node, material_name: str) -> int:
        """Row of the texture read from an Image Texture node, or -1 (with a warning) if unusable."""
        image = node.image
        if image is None:
            self._warn(f"material {material_name!r}: Image Texture node {node.name!r} has no image; using the constant colour")
            return -1
        if node.inputs["Vector"].is_linked:
            source = node.inputs["Vector"].links[0].from_node
            if source.bl_idname == "ShaderNodeUVMap":  # a named UV map: extraction reads that layer
                self._pending_uv_map = source.uv_map
            else:
                self._warn(
                    f"material {material_name!r}: image {image.name!r} uses a custom Vector input "
                    f"({source.bl_label}); sampling it with the active render UV map instead"
                )
        interpolation = "Closest" if node.interpolation == "Closest" else "Linear"
        key = (image.session_uid, interpolation)
        if key in self._texture_index:
            return self._texture_index[key]
        pixels = self._pixels(image, material_name)
        if pixels is None:
            return -1
        self._texture_index[key] = len(self._textures)
        self._textures.append(Texture(name=image.name, pixels=pixels, interpolation=interpolation))
        return self._texture_index[key]

    def _pixels(self, image, material_name: str):
        """(H, W, 3) float32 linear pixels of ``image``, or None with a warning."""
        where = f"image {image.name!r} ({_image_path(image)}) used by material {material_name!r}"
        if image.source == "TILED":
            self._warn(f"{where}: UDIM tiles are not supported; using the constant colour")
            return None
        width, height = image.size  # reading the size loads the file if it is not loaded yet
        if width * height == 0 or not image.has_data:
            self._warn(f"{where}: the image has no data (missing file?); using the constant colour")
            return None
        channels = image.channels
        flat = np.empty(width * height * channels, np.float32)
        image.pixels.foreach_get(flat)
        px = flat.reshape(height, width, channels)
        if channels >= 3:
            rgb = px[:, :, :3]
        else:  # grey (+ alpha)
            rgb = np.repeat(px[:, :, :1], 3, axis=2)
        space = image.colorspace_settings.name
        if space == "sRGB" and not image.is_float:
            # 8-bit image: Image.pixels holds exactly k/255, so decode through a 256-entry table.
            lut = srgb_to_linear(np.arange(256, dtype=np.float32) / 255.0)
            rgb = lut[np.rint(np.clip(rgb, 0.0, 1.0) * 255.0).astype(np.uint8)]
        elif space != "sRGB" and space not in _LINEAR_COLORSPACES:
            self._warn(f"{where}: colour space {space!r} is not decoded; pixels used as linear")
        if not np.isfinite(rgb).all():
            raise SceneError(f"{where}: non-finite pixel values")
        return np.ascontiguousarray(rgb, np.float32)
