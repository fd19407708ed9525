"""Reference light maps from Cycles: bake DIFFUSE (no colour) into float images, non-destructively.

What a texel holds is exactly the PDIC unit (DEVELOPERS.md): Cycles' Diffuse
bake with Direct and/or Indirect and *without* Color, i.e. irradiance E / pi
in Blender's light units, lit from the side the face normal points to.

Pixel-centre semantics
----------------------
Cycles writes a texel only if the texel's *centre* ((i + 0.5) / width,
(j + 0.5) / height in UV space) lies inside one of the object's UV triangles;
with ``margin=0`` every other texel keeps the clear colour. The images here are
RGBA float images cleared by ``use_clear`` to (0, 0, 0, 0) and Cycles writes
alpha 1 where it bakes, so ``alpha > 0.5`` is the coverage mask (measured on
Blender 5.0: a UV square [0.13, 0.63]^2 on a 16 x 16 image covers exactly texels
2..9 on both axes). With ``margin > 0`` the dilated gutter is written too and is
counted as covered.

Non-destructive: every setting, node, image, material slot, selection and the
active object is restored afterwards, also when a bake fails.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import bpy
import numpy as np

PASSES = frozenset({"DIRECT", "INDIRECT"})
_TEMP_PREFIX = "PDIC_ref_"

# Cycles settings a reference bake sets (restored afterwards).
_CYCLES_SETTINGS = (
    "device", "samples", "use_adaptive_sampling", "seed", "use_animated_seed",
    "sample_clamp_direct", "sample_clamp_indirect", "time_limit",
    "max_bounces", "diffuse_bounces", "bake_type",
)


@dataclass
class CyclesBake:
    """Result of :func:`cycles_bake_full`, keyed by object name.

    images : (height, width, 3) float32 E / pi per texel (W/m^2/sr-like Blender
        units); row 0 is the image bottom (v = 0), as ``Image.pixels``.
    coverage : (height, width) bool, True where Cycles baked the texel
        (its centre lies in a UV triangle, or the margin reached it).
    seconds : wall-clock seconds of the ``bpy.ops.object.bake`` call that baked
        the object (objects baked in the same call share the number).
    groups : object names baked together, one list per bake call.
    samples : Cycles samples per texel used.
    diffuse_bounces, max_bounces : Cycles' bounce limits the bakes ran with. The colour
        of indirect light depends on them (Sponza, relative mean R/G/B of the INDIRECT
        bake: 1.11/1.00/0.89 at 1 diffuse bounce, 1.20/1.00/0.80 at 4, 1.26/0.99/0.75 at 9),
        so a reference must be compared at PDIC's ``max_bounces``.
    """

    images: dict[str, np.ndarray] = field(default_factory=dict)
    coverage: dict[str, np.ndarray] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    groups: list[list[str]] = field(default_factory=list)
    samples: int = 0
    diffuse_bounces: int = 0
    max_bounces: int = 0

    @property
    def total_seconds(self) -> float:
        """Seconds spent in bake calls, summed over groups."""
        firsts = [self.seconds[g[0]] for g in self.groups]
        return float(sum(firsts))

    def texel_samples_per_second(self) -> float:
        """Covered texels x samples / total bake seconds (Cycles throughput)."""
        covered = sum(int(m.sum()) for m in self.coverage.values())
        return covered * self.samples / max(self.total_seconds, 1e-12)


class CyclesBakeError(RuntimeError):
    """A reference bake cannot run; the message names the object, material or setting."""


def cycles_bake(objects, uv_name: str, width: int, height: int, passes, samples: int,
                adaptive: bool = False, seed: int = 0, margin: int = 0) -> dict[str, np.ndarray]:
    """Bake Cycles' Diffuse (no Color) light maps of ``objects``: {object name: (height, width, 3) float32 E/pi}.

    See :func:`cycles_bake_full` for the parameters and for coverage masks and timings.
    """
    return cycles_bake_full(objects, uv_name, width, height, passes, samples,
                            adaptive=adaptive, seed=seed, margin=margin).images


def cycles_bake_full(objects, uv_name: str, width: int, height: int, passes, samples: int,
                     adaptive: bool = False, seed: int = 0, margin: int = 0,
                     diffuse_bounces: int | None = None, clamp_indirect: float = 0.0) -> CyclesBake:
    """Bake reference light maps with Cycles on the CPU, leaving the file as it was.

    Parameters
    ----------
    objects : list of mesh ``bpy.types.Object`` in the current view layer, visible.
    uv_name : name of the UV layer every object bakes into (e.g. "LightMap").
    width, height : image size in texels (typical 32-1024).
    passes : {"DIRECT"}, {"INDIRECT"} or both (Cycles' pass_filter; Color is always off).
    samples : Cycles samples per texel (references: 256-4096; tests: 16-64).
    adaptive : Cycles adaptive sampling; keep False for references (unbiased noise level).
    seed : Cycles seed (the animated seed is switched off).
    margin : texels of Cycles' own dilation; 0 keeps the pure pixel-centre coverage.
    diffuse_bounces : Cycles' diffuse bounce limit (and max_bounces raised to it);
        None keeps the scene's (Blender's default is 4).
    clamp_indirect : Cycles' indirect sample clamp; 0 = off (Blender's default 10 biases references).

    Returns
    -------
    CyclesBake with images, coverage masks, seconds per bake call and the groups.

    Objects are baked together when their material sets are disjoint (Cycles bakes
    into the active Image Texture node of each material, so two objects sharing a
    material must be baked in separate calls). Objects without materials, or with
    empty slots, get a temporary material, removed afterwards.
    """
    passes = frozenset(passes)
    if not passes or not passes <= PASSES:
        raise CyclesBakeError(f"passes must be a non-empty subset of {sorted(PASSES)}, got {sorted(passes)}")
    if width < 1 or height < 1:
        raise CyclesBakeError(f"image size {width}x{height} is empty")
    if samples < 1:
        raise CyclesBakeError(f"samples must be >= 1, got {samples}")
    objects = list(objects)
    _check_objects(objects, uv_name)

    context = bpy.context
    scene = context.scene
    view_layer = context.view_layer
    saved = _save_settings(scene)
    saved_selection = [ob for ob in view_layer.objects if ob.select_get(view_layer=view_layer)]
    saved_active = view_layer.objects.active
    temp_materials: list = []
    filled_slots: list = []  # (slot owner (object or mesh), slot index) given a temporary material
    appended_meshes: list = []  # meshes that got a temporary material appended
    added_nodes: list = []  # (material, node, previous active node)
    images: dict[str, bpy.types.Image] = {}
    result = CyclesBake(samples=samples)
    try:
        _fill_missing_materials(objects, temp_materials, filled_slots, appended_meshes)
        _apply_settings(scene, samples, adaptive, seed, margin, diffuse_bounces, clamp_indirect)
        result.diffuse_bounces, result.max_bounces = scene.cycles.diffuse_bounces, scene.cycles.max_bounces
        for group in _disjoint_material_groups(objects):
            # an image and an active Image Texture node in every material of the group
            for ob in group:
                image = bpy.data.images.new(f"{_TEMP_PREFIX}{ob.name}", width, height, alpha=True, float_buffer=True)
                image.colorspace_settings.is_data = True
                images[ob.name] = image
                for mat in _materials(ob):
                    nodes = mat.node_tree.nodes
                    previous = nodes.active
                    node = nodes.new("ShaderNodeTexImage")
                    node.name = node.label = f"{_TEMP_PREFIX}target"
                    node.image = image
                    nodes.active = node
                    added_nodes.append((mat, node, previous))
            for ob in view_layer.objects:
                ob.select_set(False)
            for ob in group:
                ob.select_set(True)
            view_layer.objects.active = group[0]
            start = time.perf_counter()
            bpy.ops.object.bake(type="DIFFUSE", pass_filter=set(passes), uv_layer=uv_name, margin=margin,
                                use_clear=True, target="IMAGE_TEXTURES", use_selected_to_active=False)
            seconds = time.perf_counter() - start
            result.groups.append([ob.name for ob in group])
            for ob in group:
                rgba = np.empty(width * height * 4, np.float32)
                images[ob.name].pixels.foreach_get(rgba)
                rgba = rgba.reshape(height, width, 4)
                if not np.isfinite(rgba).all():
                    raise CyclesBakeError(f"{ob.name}: Cycles baked non-finite texels")
                result.images[ob.name] = np.ascontiguousarray(rgba[..., :3])
                result.coverage[ob.name] = rgba[..., 3] > 0.5
                result.seconds[ob.name] = seconds
            _remove_nodes(added_nodes)
    finally:
        _remove_nodes(added_nodes)
        for image in images.values():
            bpy.data.images.remove(image)
        _remove_temporary_materials(temp_materials, filled_slots, appended_meshes)
        _restore_settings(scene, saved)
        for ob in view_layer.objects:
            ob.select_set(ob in saved_selection)
        view_layer.objects.active = saved_active
    return result


# --------------------------------------------------------------------------- checks
def _check_objects(objects, uv_name: str) -> None:
    if not objects:
        raise CyclesBakeError("no objects to bake")
    if bpy.context.mode != "OBJECT":
        raise CyclesBakeError(f"Cycles bakes in Object Mode; the context is in {bpy.context.mode}")
    names = set()
    view_layer = bpy.context.view_layer
    for ob in objects:
        if ob.type != "MESH":
            raise CyclesBakeError(f"{ob.name}: only mesh objects can be baked, got {ob.type}")
        if ob.name in names:
            raise CyclesBakeError(f"{ob.name}: listed twice")
        names.add(ob.name)
        if view_layer.objects.get(ob.name) is None or not ob.visible_get(view_layer=view_layer):
            raise CyclesBakeError(f"{ob.name}: not visible in view layer {view_layer.name!r}; Cycles cannot bake it")
        if uv_name not in ob.data.uv_layers:
            raise CyclesBakeError(f"{ob.name}: mesh {ob.data.name!r} has no UV layer {uv_name!r} "
                                  f"(has {list(ob.data.uv_layers.keys())})")
        _check_texture_uvs(ob, uv_name)
        for mat in _materials(ob):
            if mat.node_tree is None:
                raise CyclesBakeError(f"{ob.name}: material {mat.name!r} has no node tree")
            if mat.library is not None:
                raise CyclesBakeError(f"{ob.name}: material {mat.name!r} is linked from a library and cannot take a bake node")


def _check_texture_uvs(ob, uv_name: str) -> None:
    """Refuse a bake whose light-map UV map is the one textures render with.

    An Image Texture node without a UV Map node samples the mesh's *active render*
    UV map, in the bake as in a render (Sponza, measured: making the light map
    render shifts the indirect mean by +8 % in red); PDIC samples textures with
    the render map, so a reference baked this way is not the same scene.
    """
    layers = ob.data.uv_layers
    renders = next((layer.name for layer in layers if layer.active_render), None)
    if renders != uv_name or len(layers) < 2:
        return
    for mat in _materials(ob):
        if mat.node_tree is None:
            continue
        for node in mat.node_tree.nodes:
            if node.type == "TEX_IMAGE" and not node.inputs["Vector"].is_linked:
                others = [layer.name for layer in layers if layer.name != uv_name]
                raise CyclesBakeError(
                    f"{ob.name}: UV map {uv_name!r} is the active render map, so Image Texture node "
                    f"{node.name!r} of material {mat.name!r} would sample it; make the texture map "
                    f"({others[0]!r}) render or give the node a UV Map node")


def _materials(ob) -> list:
    """Distinct materials in the object's slots (in slot order)."""
    out = []
    for slot in ob.material_slots:
        if slot.material is not None and slot.material not in out:
            out.append(slot.material)
    return out


# --------------------------------------------------------------------------- grouping
def _disjoint_material_groups(objects) -> list[list]:
    """Greedy first-fit: objects whose material sets do not intersect share a bake call."""
    groups: list[tuple[list, set]] = []
    for ob in objects:
        mats = {m.name for m in _materials(ob)}
        for members, used in groups:
            if not (mats & used):
                members.append(ob)
                used |= mats
                break
        else:
            groups.append(([ob], set(mats)))
    return [members for members, _ in groups]


# --------------------------------------------------------------------------- temporary materials
def _fill_missing_materials(objects, temp_materials, filled_slots, appended_meshes) -> None:
    """Give every object a material in every slot (Cycles needs a node to bake into)."""
    for ob in objects:
        if len(ob.material_slots) == 0:
            if ob.data in appended_meshes:
                continue  # a linked duplicate already got one through the shared mesh
            mat = _new_temp_material(f"{_TEMP_PREFIX}{ob.name}", temp_materials)
            ob.data.materials.append(mat)
            appended_meshes.append(ob.data)
            continue
        for index, slot in enumerate(ob.material_slots):
            if slot.material is None:
                mat = _new_temp_material(f"{_TEMP_PREFIX}{ob.name}_{index}", temp_materials)
                owner = ob if slot.link == "OBJECT" else ob.data
                owner.materials[index] = mat
                filled_slots.append((owner, index))


def _new_temp_material(name: str, temp_materials: list):
    mat = bpy.data.materials.new(name)
    temp_materials.append(mat)
    return mat


def _remove_temporary_materials(temp_materials, filled_slots, appended_meshes) -> None:
    for owner, index in reversed(filled_slots):
        owner.materials[index] = None
    filled_slots.clear()
    for mesh in appended_meshes:
        mesh.materials.clear()  # it had none; pop() would leave the objects' slot counts stale
    appended_meshes.clear()
    for mat in temp_materials:
        bpy.data.materials.remove(mat)
    temp_materials.clear()


def _remove_nodes(added_nodes) -> None:
    """Remove the bake nodes and restore each material's active node (last added first)."""
    for mat, node, previous in reversed(added_nodes):
        nodes = mat.node_tree.nodes
        nodes.remove(node)
        nodes.active = previous
    added_nodes.clear()


# --------------------------------------------------------------------------- settings
def _bake_setting_names(scene) -> list[str]:
    return [p.identifier for p in scene.render.bake.bl_rna.properties
            if not p.is_readonly and p.type in {"BOOLEAN", "INT", "FLOAT", "ENUM", "STRING"}
            and not getattr(p, "is_array", False) and p.identifier != "rna_type"]


def _save_settings(scene) -> dict:
    bake = scene.render.bake
    return {
        "engine": scene.render.engine,
        "cycles": {name: getattr(scene.cycles, name) for name in _CYCLES_SETTINGS},
        "bake": {name: getattr(bake, name) for name in _bake_setting_names(scene)},
    }


def _apply_settings(scene, samples, adaptive, seed, margin, diffuse_bounces, clamp_indirect) -> None:
    scene.render.engine = "CYCLES"
    cycles = scene.cycles
    cycles.device = "CPU"
    cycles.samples = samples
    cycles.use_adaptive_sampling = adaptive
    cycles.seed = seed
    cycles.use_animated_seed = False
    cycles.sample_clamp_direct = 0.0
    cycles.sample_clamp_indirect = clamp_indirect
    cycles.time_limit = 0.0
    if diffuse_bounces is not None:
        cycles.diffuse_bounces = diffuse_bounces
        cycles.max_bounces = max(cycles.max_bounces, diffuse_bounces)
    scene.render.bake.margin = margin


def _restore_settings(scene, saved: dict) -> None:
    scene.render.engine = saved["engine"]
    for name, value in saved["cycles"].items():
        setattr(scene.cycles, name, value)
    for name, value in saved["bake"].items():
        setattr(scene.render.bake, name, value)


DIRECT_SPP = 256
"""Samples per pixel of the committed direct-light references (bench/references/)."""


def reference(objects, res, spp, passes, bounces, cache_dir: Path, tag: str):
    """Cycles bake of ``objects``' LightMap UVs, read from ``cache_dir`` when made before (committed
    references live in bench/references/): (images, coverage, seconds)."""
    path = cache_dir / f"{tag}_{res}_{spp}_{bounces}_{'_'.join(sorted(passes))}.npz"
    if path.exists():
        data = np.load(path)
        return {k[4:]: data[k] for k in data if k.startswith("img_")}, {k[4:]: data[k] for k in data if k.startswith("cov_")}, float(data["seconds"])
    t = time.perf_counter()
    result = cycles_bake_full(objects, "LightMap", res, res, set(passes), spp, diffuse_bounces=bounces)
    seconds = time.perf_counter() - t
    cache_dir.mkdir(parents=True, exist_ok=True)
    np.savez(path, seconds=seconds, **{f"img_{k}": v for k, v in result.images.items()},
             **{f"cov_{k}": v for k, v in result.coverage.items()})
    return result.images, result.coverage, seconds
