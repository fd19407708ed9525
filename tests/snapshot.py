"""A plain-data snapshot of everything a bake could touch in the open .blend.

Tests compare ``snapshot(bpy)`` before and after a bake, a failed bake or a
Clear: equal snapshots mean the file was left (or restored) exactly as it was.
Import it as ``from snapshot import snapshot`` (pytest puts tests/ on sys.path).
"""
from __future__ import annotations

import numpy as np

from pdic.pdic_addon import writeback


def _value(v):
    if hasattr(v, "__len__") and not isinstance(v, str):
        return tuple(round(float(x), 6) for x in v)
    if isinstance(v, float):
        return round(v, 6)
    return v if isinstance(v, (int, str, bool, type(None))) else str(v)


def _tree(tree):
    if tree is None:
        return None
    nodes = {}
    for n in tree.nodes:
        inputs = tuple((s.identifier, _value(s.default_value)) for s in n.inputs if hasattr(s, "default_value"))
        nodes[n.name] = (n.bl_idname, inputs, getattr(n, "image", None) and n.image.name)
    links = sorted((l.from_node.name, l.from_socket.identifier, l.to_node.name, l.to_socket.identifier)
                   for l in tree.links)
    return nodes, links


def snapshot(bpy) -> dict:
    """Everything a bake could touch, as plain comparable data.

    Data-block names per kind; per object its material slots (link, material, object-linked
    material) and custom-property keys; per mesh its UV maps (names, active, render flags,
    coordinates), attributes, materials and users; per material its node tree (nodes, inputs,
    images, links), fake user, keys, users, viewport colour; per image its path, source,
    packing, users and size.
    """
    s = {}
    for kind in ("objects", "meshes", "materials", "images", "scenes", "node_groups", "texts", "cameras", "lights"):
        s[kind + "_names"] = sorted(i.name for i in getattr(bpy.data, kind))
    s["objects"] = {}
    for o in bpy.data.objects:
        slots = []
        for slot in o.material_slots:
            slots.append((slot.link, slot.material and slot.material.name,
                          writeback._object_material(slot) and writeback._object_material(slot).name))
        s["objects"][o.name] = (slots, sorted(o.keys()))
    s["meshes"] = {}
    for m in bpy.data.meshes:
        uv = {l.name: np.round(np.array([d.vector[:] for d in l.uv]), 6).tobytes() for l in m.uv_layers}
        s["meshes"][m.name] = (
            [l.name for l in m.uv_layers], m.uv_layers.active_index,
            [l.active_render for l in m.uv_layers], sorted(a.name for a in m.attributes),
            [mat and mat.name for mat in m.materials], uv, m.users)
    s["materials"] = {m.name: (_tree(m.node_tree), m.use_fake_user, sorted(m.keys()), m.users,
                               tuple(round(c, 6) for c in m.diffuse_color)) for m in bpy.data.materials}
    s["images"] = {i.name: (i.filepath, i.source, bool(i.packed_file), i.users, tuple(i.size))
                   for i in bpy.data.images}
    return s
