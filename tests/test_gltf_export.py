"""glTF export with light maps (pdic_addon/gltf_export.py) on the real bpy wheel and its glTF exporter."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pdic.pdic_addon import gltf_export as g

ROOT = Path(__file__).resolve().parents[1]


def test_rgbm_round_trip_error_is_below_half_a_step_of_the_brightest_channel(rng):
    rgb = rng.random((32, 32, 3)) * np.array([0.1, 3.0, 7.0])
    value_range = g.rgbm_range(rgb)
    assert value_range == 8.0
    decoded = g.decode_rgbm(g.encode_rgbm(rgb, value_range), value_range)
    peak = rgb.max(axis=2)
    step = np.maximum(peak, value_range / 255) / 255  # a's step bounds the max channel's scale
    assert (np.abs(decoded - rgb).max(axis=2) <= step * 1.01).all()


def test_glb_container_round_trips():
    doc = {"asset": {"version": "2.0"}, "buffers": [{"byteLength": 5}]}
    back, binary = g.read_glb(g.write_glb(doc, b"abcde"))
    assert back == doc and binary[:5] == b"abcde"


def test_bad_glb_is_named():
    with pytest.raises(g.ExportError, match="not a glTF"):
        g.read_glb(b"\0" * 20)


def bake_cornell(bpy, tmp_path, atlas_size=0):
    from pdic.core.settings import preset
    from pdic.pdic_addon.job import BakeJob

    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "sample_blends" / "cornell_point.blend"))
    settings = preset("PREVIEW", photons=20_000, default_resolution=32, threads=2)
    job = BakeJob(bpy.context, settings, output_folder=str(tmp_path / "maps"), atlas_size=atlas_size)
    job.run()
    return job


def test_export_binds_lightmap_uvs_as_texcoord_1_with_original_materials(tmp_path, registered):
    import bpy

    from pdic.pdic_addon import writeback

    job = bake_cornell(bpy, tmp_path, atlas_size=256)
    before = {o.name: [s.material.name for s in o.material_slots] for o in bpy.context.scene.objects
              if o.type == "MESH"}
    path = g.export_glb(bpy.context, tmp_path / "cornell.glb")
    after = {o.name: [s.material.name for s in o.material_slots] for o in bpy.context.scene.objects
             if o.type == "MESH"}
    assert before == after  # baked shading shown again after the export
    assert any(writeback.is_baked_shading(o) for o in bpy.context.scene.objects)
    doc, binary = g.read_glb(path.read_bytes())
    assert g.EXTENSION in doc["extensionsUsed"]
    assert len(doc["extras"]["pdic"]["lightmaps"]) == 1  # one shared atlas
    nodes = {n["name"]: n for n in doc["nodes"]}
    for name in job.extraction.target_objects:
        for prim in doc["meshes"][nodes[name]["mesh"]]["primitives"]:
            assert "TEXCOORD_1" in prim["attributes"]
            material = doc["materials"][prim["material"]]
            assert ".PDIC." not in material["name"]  # the user's material, not PDIC's emission copy
            assert "KHR_materials_emissive_strength" not in material.get("extensions", {})
            assert material["extensions"][g.EXTENSION]["texCoord"] == 1
            assert material["extras"]["pdic_lightmap"]["encoding"] == "RGBM"
    # TEXCOORD_1 holds the PDIC_Lightmap UVs (glTF flips v)
    floor = bpy.data.objects["Floor"].data
    uv = np.empty(len(floor.loops) * 2, np.float32)
    floor.uv_layers["PDIC_Lightmap"].uv.foreach_get("vector", uv)
    accessor = doc["accessors"][doc["meshes"][nodes["Floor"]["mesh"]]["primitives"][0]["attributes"]["TEXCOORD_1"]]
    view = doc["bufferViews"][accessor["bufferView"]]
    data = np.frombuffer(binary, np.float32, accessor["count"] * 2,
                         view.get("byteOffset", 0) + accessor.get("byteOffset", 0)).reshape(-1, 2)
    exported = {(round(float(u), 5), round(1.0 - float(v), 5)) for u, v in data}
    assert exported == {(round(float(u), 5), round(float(v), 5)) for u, v in uv.reshape(-1, 2)}


def test_export_without_a_bake_names_the_problem(tmp_path, registered):
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "sample_blends" / "cornell_point.blend"))
    with pytest.raises(g.ExportError, match="bake first"):
        g.export_glb(bpy.context, tmp_path / "x.glb")
    assert not (tmp_path / "x.glb").exists()
