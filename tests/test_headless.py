"""pdic_bake.py in a subprocess (bpy wheel): outputs, manifest, exit codes, the .blend left untouched."""
from __future__ import annotations

import hashlib
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

from pdic.core import manifest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "pdic_bake.py"
FAST = ["--quality", "CUSTOM", "--photons", "4000", "--resolution", "32", "--threads", "1"]


def run(*args, timeout=240):
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout)


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def scene_blend(blender, tmp_path):
    """A saved floor + box + point light + camera scene; returns a maker (light on/off)."""

    def make(light=True, name="scene.blend"):
        bpy = blender
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.mesh.primitive_plane_add(size=6)
        bpy.context.object.name = "Floor"
        floor_mat = bpy.data.materials.new("FloorMat")
        bpy.context.object.data.materials.append(floor_mat)
        bpy.ops.mesh.primitive_cube_add(size=1, location=(0, 0, 0.5))
        bpy.context.object.name = "Box"
        if light:
            bpy.ops.object.light_add(type="POINT", location=(0, 0, 3))
            bpy.context.object.data.energy = 300.0
        bpy.ops.object.camera_add(location=(0, -6, 4), rotation=(0.9, 0, 0))
        bpy.context.scene.camera = bpy.context.object
        path = tmp_path / name
        bpy.ops.wm.save_as_mainfile(filepath=str(path))
        return path

    return make


def read_png(path: Path) -> np.ndarray:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    w, h = struct.unpack(">II", data[16:24])
    pos, idat = 8, b""
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        if kind == b"IDAT":
            idat += data[pos + 8:pos + 8 + length]
        pos += 12 + length
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, 1 + 3 * w)
    assert (raw[:, 0] == 0).all()  # filter type None, as written
    return raw[:, 1:].reshape(h, w, 3)


def test_headless_bake_writes_images_manifest_and_preview(scene_blend, tmp_path):
    blend = scene_blend()
    before = digest(blend)
    out = tmp_path / "maps"
    png = tmp_path / "look.png"
    r = run("--blend", blend, "--output", out, "--preview-png", png, "--preview-width", "96", *FAST)
    assert r.returncode == 0, r.stderr
    assert digest(blend) == before  # the .blend on disk is untouched
    doc = manifest.read_manifest(out)
    entries = {e["name"]: e for e in doc["objects"]}
    assert set(entries) == {"Floor", "Box"}
    for name, e in entries.items():
        assert e["image"] == f"scene.PDIC_{name}.exr" and (out / e["image"]).is_file()
        assert e["uv_map"] == "PDIC_Lightmap" and (e["width"], e["height"]) == (32, 32)
        assert 0 < e["texels"] <= 32 * 32
    assert doc["settings"]["photons"] == 4000 and doc["settings"]["quality"] == "CUSTOM"
    assert doc["stats"]["seconds_total"] > 0 and "addon_unwrap" in doc["stats"]["seconds"]
    # the report names stages, texel counts and output paths
    assert "stage times" in r.stdout and "32x32 texels" in r.stdout and str(out / "scene.PDIC_Floor.exr") in r.stdout
    assert "kernels: compiled (pdic_native-" in r.stdout  # the headless bake says how Equation 3 ran
    # preview: the lit floor under the lamp is brighter than the unlit sky corner
    image = read_png(png)
    assert image.shape == (54, 96, 3)
    assert image[40, 48].mean() > image[0, 0].mean() + 20


def test_direct_samples_option_reaches_the_bake(scene_blend, tmp_path):
    """--direct-samples sets the shadow rays per sample toward soft lights: the manifest records it."""
    out = tmp_path / "maps"
    r = run("--blend", scene_blend(), "--output", out, *FAST, "--direct-samples", "3")
    assert r.returncode == 0, r.stderr
    assert manifest.read_manifest(out)["settings"]["direct_samples"] == 3


def test_uv_map_option_bakes_into_the_objects_own_layouts(scene_blend, tmp_path):
    """--uv-map UVMap: the plane's and the cube's own UVs (a full square, the cube's unfolded cross) hold
    their light maps as laid out; a name no mesh has is an error naming it."""
    blend = scene_blend()
    out = tmp_path / "maps"
    r = run("--blend", blend, "--output", out, *FAST, "--uv-map", "UVMap")
    assert r.returncode == 0, r.stderr
    assert "2 objects bake into their UV map 'UVMap'" in r.stdout
    entries = {e["name"]: e for e in manifest.read_manifest(out)["objects"]}
    assert {n: e.get("uv_source") for n, e in entries.items()} == {"Floor": "UVMap", "Box": "UVMap"}
    r = run("--blend", blend, "--output", tmp_path / "other", *FAST, "--uv-map", "UV2")
    assert r.returncode == 1 and "--uv-map 'UV2': no mesh to bake has a UV map of that name" in r.stderr


def test_save_blend_keeps_light_maps_linked_to_uv_map(scene_blend, tmp_path, blender):
    blend = scene_blend()
    saved = tmp_path / "baked.blend"
    r = run("--blend", blend, "--save-blend", saved, "--objects", "Floor", *FAST)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "pdic_lightmaps" / "scene.PDIC_Floor.exr").is_file()  # default //pdic_lightmaps/
    blender.ops.wm.open_mainfile(filepath=str(saved))
    floor = blender.data.objects["Floor"]
    assert "PDIC_Lightmap" in floor.data.uv_layers and "PDIC_Box" not in blender.data.images
    image = blender.data.images["PDIC_Floor"]
    assert image.filepath == "//pdic_lightmaps/scene.PDIC_Floor.exr" and len(image.pixels) == 32 * 32 * 4
    assert floor.material_slots[0].link == "OBJECT" and floor.material_slots[0].material.name == "FloorMat.PDIC.Floor"


def test_scene_without_light_exits_nonzero_and_leaves_no_output(scene_blend, tmp_path):
    blend = scene_blend(light=False)
    before = digest(blend)
    r = run("--blend", blend, "--output", tmp_path / "maps", *FAST)
    assert r.returncode == 1
    assert "pdic_bake: error:" in r.stderr and "emits light" in r.stderr
    assert digest(blend) == before and not (tmp_path / "maps").exists()


def test_readonly_output_exits_nonzero_naming_the_folder(scene_blend, tmp_path):
    blend = scene_blend()
    before = digest(blend)
    r = run("--blend", blend, "--output", "/proc/pdic_maps", *FAST)
    assert r.returncode == 1 and "/proc/pdic_maps" in r.stderr
    assert digest(blend) == before


def test_unsaved_scene_needs_an_output_folder():
    r = run(*FAST)  # no --blend: the bpy wheel's unsaved startup scene
    assert r.returncode == 1 and "not saved" in r.stderr and "--output" in r.stderr


def test_bad_input_names_the_culprit(scene_blend, tmp_path):
    blend = scene_blend()
    r = run("--blend", blend, "--objects", "Nope", "--output", tmp_path / "o", *FAST)
    assert r.returncode == 1 and "'Nope'" in r.stderr
    r = run("--blend", tmp_path / "missing.blend", *FAST)
    assert r.returncode == 1 and "missing.blend" in r.stderr
    r = run("--blend", blend, "--passes", "diract", *FAST)
    assert r.returncode == 2 and "diract" in r.stderr


# --------------------------------------------------------------------------- issue 14
def folder_state(folder: Path):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())} if folder.exists() else None


@pytest.mark.parametrize("how", ["same", "relative", "symlink"])
def test_save_blend_never_overwrites_the_input(scene_blend, tmp_path, how):
    blend = scene_blend()
    before = digest(blend)
    target = {"same": blend, "relative": Path("..") / blend.name}.get(how)
    if how == "symlink":
        target = tmp_path / "link.blend"
        target.symlink_to(blend)
    cwd = tmp_path / "work"
    cwd.mkdir()
    r = subprocess.run([sys.executable, str(SCRIPT), "--blend", str(blend), "--save-blend", str(target), *FAST],
                       cwd=cwd, capture_output=True, text=True, timeout=240)
    assert r.returncode == 2 and "--save-blend" in r.stderr and "being baked" in r.stderr
    assert digest(blend) == before and not (tmp_path / "pdic_lightmaps").exists()


@pytest.mark.parametrize("option, value", [("--seed", "-1"), ("--threads", "-1"), ("--photons", "-1"),
                                           ("--texel-density", "inf"), ("--texel-density", "nan"),
                                           ("--direct-samples", "0")])
def test_bad_numbers_exit_2_naming_the_option(option, value):
    args = [a for a in FAST if a not in ("--resolution", "32")] if option == "--texel-density" else FAST
    r = run(*args, option, value)
    assert r.returncode == 2 and option in r.stderr and "choose_resolution" not in r.stderr, r.stderr


def test_preview_without_a_camera_fails_before_any_output(blender, tmp_path):
    blender.ops.wm.read_factory_settings(use_empty=True)
    blender.ops.mesh.primitive_plane_add(size=6)
    blender.ops.object.light_add(type="POINT", location=(0, 0, 3))
    blend = tmp_path / "nocam.blend"
    blender.ops.wm.save_as_mainfile(filepath=str(blend))
    r = run("--blend", blend, "--output", tmp_path / "maps", "--preview-png", tmp_path / "p.png", *FAST)
    assert r.returncode == 2 and "camera" in r.stderr
    assert not (tmp_path / "maps").exists() and not (tmp_path / "p.png").exists()


def test_too_many_photons_are_refused_with_a_memory_estimate(scene_blend, tmp_path):
    blend = scene_blend()
    r = run("--blend", blend, "--output", tmp_path / "maps", *FAST, "--photons", "1000000000000")
    assert r.returncode == 1 and "Photons" in r.stderr and "GiB of memory" in r.stderr, r.stderr
    assert "MemoryError" not in r.stderr and not (tmp_path / "maps").exists()


def test_ctrl_c_cancels_exits_130_and_leaves_outputs_as_they_were(scene_blend, tmp_path):
    import signal
    import time

    blend = scene_blend()
    out = tmp_path / "maps"
    assert run("--blend", blend, "--output", out, *FAST).returncode == 0
    before = folder_state(out)
    slow = ["--quality", "CUSTOM", "--photons", "50000000", "--resolution", "32", "--threads", "1", "--seed", "5"]
    p = subprocess.Popen([sys.executable, str(SCRIPT), "--blend", str(blend), "--output", str(out), *slow],
                         cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for line in p.stdout:  # wait until the bake is under way
        if "photons" in line.lower() and ".." in line:
            break
    time.sleep(0.5)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert "cancel" in err and folder_state(out) == before
