"""The extension package: manifest, build and install through Blender's own machinery.

The build downloads the linux-x64 wheels (cp311 and cp313) once (PyPI) into the wheel
cache (``~/.cache/pdic/wheels`` or ``$PDIC_WHEEL_CACHE``) and reuses them afterwards.
The zip is installed into every Blender of tools/blender_matrix.py built for the Python
running this suite (3.11: 4.2, 4.5, 5.0; 3.13: 5.1, 5.2), each in its own venv holding
only bpy and numpy, in a subprocess with its own ``BLENDER_USER_RESOURCES``, so the
test session's Blender never sees the installed extension.
"""
from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import textwrap
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PLATFORM = "linux-x64"
BUNDLED = ("scipy", "embreex", "xatlas")
# Sun strength of the install test's scene, W/m^2: a texel facing it holds E/pi = S/pi (DEVELOPERS.md, Units).
SUN_STRENGTH = 3.0


def _load_tool(name: str):
    spec = importlib.util.spec_from_file_location(f"pdic_{name}", ROOT / "tools" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


build_extension = _load_tool("build_extension")
blender_matrix = _load_tool("blender_matrix")
# The Blenders whose Python runs this suite; the other Python's suite installs into the others.
BLENDERS = blender_matrix.for_python()


def _version(text: str) -> tuple[int, ...]:
    return tuple(int(part) for part in text.split("."))


def blender_ext(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(build_extension.blender_ext_path()), *args],
                          capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="module")
def built_zip(tmp_path_factory) -> Path:
    """The linux-x64 extension zip, built by tools/build_extension.py into a temporary dist/."""
    work = tmp_path_factory.mktemp("build")
    proc = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "build_extension.py"), "--platform", PLATFORM,
         "--dist", str(work / "dist"), "--staging", str(work / "staging")],
        capture_output=True, text=True, timeout=900,
    )
    assert proc.returncode == 0, f"build failed:\n{proc.stdout}\n{proc.stderr}"
    zips = sorted((work / "dist").glob("*.zip"))
    version = tomllib.loads((ROOT / "blender_manifest.toml").read_text())["version"]
    assert [z.name for z in zips] == [f"pdic-{version}-{PLATFORM.replace('-', '_')}.zip"], proc.stdout
    return zips[0]


def test_source_manifest_passes_blenders_validator():
    proc = blender_ext("validate", "--valid-tags", str(build_extension.valid_tags_path()), str(ROOT))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Success" in proc.stdout


def test_validator_rejects_a_tag_blender_does_not_know(tmp_path):
    """The validation above is strict: with Blender's tag list an unknown tag fails."""
    text = (ROOT / "blender_manifest.toml").read_text()
    bad = text.replace('tags = ["Lighting", "Bake"]', 'tags = ["Lighting", "Not A Blender Tag"]')
    assert bad != text
    (tmp_path / "blender_manifest.toml").write_text(bad)
    shutil.copy2(ROOT / "__init__.py", tmp_path / "__init__.py")
    proc = blender_ext("validate", "--valid-tags", str(build_extension.valid_tags_path()), str(tmp_path))
    assert proc.returncode != 0
    assert "Not A Blender Tag" in proc.stdout + proc.stderr


def test_source_manifest_declares_what_the_extension_is():
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert (manifest["id"], manifest["type"]) == ("pdic", "add-on")
    assert "wheels" not in manifest, "wheels are added by tools/build_extension.py, never listed in the source"
    excluded = manifest["build"]["paths_exclude_pattern"]
    for pattern in ("/tests/", "/bench/", "/tools/", "/.ci/", "/.venv/", "/sample_blends/", "/dist/", "__pycache__/"):
        assert pattern in excluded


def test_manifest_admits_every_tested_blender_from_the_first_4_2_that_filters_wheels_by_python():
    """min: the oldest tested 4.2, which filters wheels by Python (4.2.0 does not);
    max (exclusive): the release after the newest tested."""
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    low, high = _version(manifest["blender_version_min"]), _version(manifest["blender_version_max"])
    tested = sorted(_version(b.bpy) for b in blender_matrix.BLENDERS)
    assert low == tested[0] == (4, 2, 13)
    assert all(low <= v < high for v in tested)
    newest = tested[-1]
    assert high == (newest[0], newest[1] + 1, 0), "the maximum admits every patch of the newest tested line, no more"
    # Every Blender line from 4.2 LTS to the newest is tested: 4.2, 4.5, 5.0, 5.1, 5.2.
    assert [b.line for b in blender_matrix.BLENDERS] == ["4.2 LTS", "4.5 LTS", "5.0", "5.1", "5.2 LTS"]


def test_every_bundled_wheel_is_pinned_for_both_blender_pythons():
    pins = {py: build_extension.pinned_versions(requirements=path)
            for py, path in build_extension.BLENDER_PYTHONS.items()}
    assert sorted(pins) == ["3.11", "3.13"]
    assert sorted(blender_matrix.REQUIREMENTS) == sorted(pins)
    assert {b.python for b in blender_matrix.BLENDERS} == set(pins)


def test_linux_build_holds_package_and_wheels_but_no_dev_files(built_zip):
    with zipfile.ZipFile(built_zip) as zf:
        names = zf.namelist()
        inner = tomllib.loads(zf.read("blender_manifest.toml").decode())
    # Every module of the package is there.
    for folder in ("core", "pdic_addon"):
        for path in (ROOT / folder).rglob("*.py"):
            if "__pycache__" not in path.parts:
                assert path.relative_to(ROOT).as_posix() in names, f"{path} missing from {built_zip.name}"
    assert "__init__.py" in names
    # The bundled wheels, for this platform only, one per Blender Python; numpy comes with Blender.
    wheels = [n for n in names if n.endswith(".whl")]
    assert sorted((Path(w).name.split("-")[0], Path(w).name.split("-")[2]) for w in wheels) == sorted(
        (name, tag) for name in BUNDLED for tag in ("cp311", "cp313"))
    assert all(w.startswith("wheels/") and "x86_64" in w for w in wheels), wheels
    assert sorted(inner["wheels"]) == sorted(f"./{w}" for w in wheels)
    assert inner["build"]["generated"]["platforms"] == [PLATFORM]
    # The compiled kernels of this platform, built by zig, with their source; no import library or object file.
    assert sorted(n for n in names if n.startswith("core/native/")) == [
        "core/native/pdic_native-linux-x64.so", "core/native/pdic_native.c"]
    assert zf_bytes(built_zip, "core/native/pdic_native-linux-x64.so")[:4] == b"\x7fELF"
    # Nothing from development.
    dev = [n for n in names if n.split("/")[0] in {"tests", "bench", "tools", ".ci", ".venv", "sample_blends", "out",
                                                   "dist", "build", "pdic_bootstrap.py", "pdic_bake.py",
                                                   "requirements.txt", "requirements-py313.txt", "DEVELOPERS.md",
                                                   "README.md", ".gitignore"}
           or "__pycache__" in n or n.endswith(".pyc")]
    assert dev == [], f"development files in the extension: {dev}"


def zf_bytes(path: Path, name: str) -> bytes:
    with zipfile.ZipFile(path) as zf:
        return zf.read(name)


def test_built_zip_passes_blenders_validator(built_zip):
    proc = blender_ext("validate", "--valid-tags", str(build_extension.valid_tags_path()), str(built_zip))
    assert proc.returncode == 0, proc.stdout + proc.stderr


# Runs in a fresh interpreter: install the zip with Blender's operator, enable it,
# then bake a 32x32 light map of a plane under a sun through the installed operator.
INSTALL_SCRIPT = r'''
import json, os, sys, time, traceback
import bpy

zip_path, work, sun_strength = sys.argv[1], sys.argv[2], float(sys.argv[3])
report = {"errors": {}, "blender_version": "%d.%d.%d" % bpy.app.version,
          "python": "%d.%d" % sys.version_info[:2]}

def step(name, fn):
    t0 = time.perf_counter()
    try:
        return fn()
    except Exception:
        report["errors"][name] = traceback.format_exc()
    finally:
        report.setdefault("seconds", {})[name] = time.perf_counter() - t0

def install():
    user_repo = next(r for r in bpy.context.preferences.extensions.repos if r.module == "user_default")
    report["repo_directory"] = user_repo.directory
    bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)

step("install", install)
report["installed_files"] = sorted(os.listdir(os.path.join(report.get("repo_directory", ""), "pdic"))) \
    if os.path.isdir(os.path.join(report.get("repo_directory", ""), "pdic")) else []
report["addons"] = [a.module for a in bpy.context.preferences.addons]
site = os.path.join(bpy.utils.user_resource("EXTENSIONS"), ".local", "lib",
                    "python%d.%d" % sys.version_info[:2], "site-packages")
report["site_packages"] = sorted(os.listdir(site)) if os.path.isdir(site) else []
report["site_directory"] = site
# The tags of each unpacked wheel (its WHEEL file): which Python's wheels Blender chose.
report["wheel_tags"] = {}
for entry in report["site_packages"]:
    wheel_file = os.path.join(site, entry, "WHEEL")
    if entry.endswith(".dist-info") and os.path.isfile(wheel_file):
        with open(wheel_file, encoding="utf-8") as f:
            report["wheel_tags"][entry] = [ln.split(":", 1)[1].strip() for ln in f if ln.startswith("Tag:")]
report["pdic_module"] = getattr(sys.modules.get("bl_ext.user_default.pdic"), "__file__", None)
report["pdic_ops"] = sorted(dir(bpy.ops.pdic)) if hasattr(bpy.ops, "pdic") else []

def bake():
    scene = bpy.context.scene
    scene.world = None
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    bpy.ops.mesh.primitive_plane_add(size=2.0, location=(0.0, 0.0, 0.0))
    plane = bpy.context.active_object
    plane.name = "Plane"
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", type="SUN"))
    sun.data.energy = sun_strength
    scene.collection.objects.link(sun)
    out = os.path.join(work, "lightmaps")
    props = scene.pdic
    props.quality = "CUSTOM"
    props.photons = 1000
    props.max_bounces = 1
    props.hemisphere_theta = 2
    props.hemisphere_phi = 4
    props.default_resolution = 32
    props.texel_density = 0.0
    props.output_folder = out + os.sep
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(work, "tiny.blend"))
    report["bake_result"] = sorted(bpy.ops.pdic.bake())
    with open(os.path.join(out, "pdic_manifest.json"), encoding="utf-8") as f:
        manifest = json.load(f)
    report["manifest_objects"] = manifest["objects"]
    entry = next(o for o in manifest["objects"] if o["name"] == "Plane")
    image = bpy.data.images.load(os.path.join(out, entry["image"]), check_existing=False)
    import numpy as np
    pixels = np.empty(image.size[0] * image.size[1] * 4, dtype=np.float32)
    image.pixels.foreach_get(pixels)
    rgba = pixels.reshape(-1, 4)
    covered = rgba[:, 3] > 0.5
    report["kernels"] = manifest["stats"]["kernels"]
    report["module_files"] = {name: getattr(sys.modules.get(name), "__file__", None)
                              for name in ("scipy", "embreex", "xatlas", "numpy")}
    report["image"] = {
        "size": list(image.size), "finite": bool(np.isfinite(rgba).all()),
        "covered_fraction": float(covered.mean()),
        "mean_rgb_covered": rgba[covered, :3].mean(axis=0).tolist() if covered.any() else None,
    }

step("bake", bake)
print("PDIC_REPORT " + json.dumps(report))
'''


@pytest.fixture(scope="module", params=BLENDERS, ids=lambda b: b.id)
def installed(request, built_zip, tmp_path_factory) -> dict:
    """Install the built zip into one Blender's temporary user extension repository; the subprocess's report."""
    blender = request.param
    python = blender_matrix.interpreter(blender)  # its own venv: bpy and numpy only
    work = tmp_path_factory.mktemp(f"install-{blender.id}")
    script = work / "install_and_bake.py"
    script.write_text(textwrap.dedent(INSTALL_SCRIPT))
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("BLENDER_", "VIRTUAL_ENV")) and k not in ("PYTHONPATH", "PYTHONHOME")}
    env["BLENDER_USER_RESOURCES"] = str(work / "blender_user")
    # cwd and the script's folder are outside the repo: the extension must import from where Blender put it.
    proc = subprocess.run([str(python), str(script), str(built_zip), str(work), str(SUN_STRENGTH)],
                          cwd=work, env=env, capture_output=True, text=True, timeout=900)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("PDIC_REPORT ")]
    assert proc.returncode == 0 and lines, f"install subprocess failed in {blender.id}:\n{proc.stdout}\n{proc.stderr}"
    report = json.loads(lines[-1][len("PDIC_REPORT "):])
    report["blender"] = blender
    report["log"] = proc.stdout[-4000:] + proc.stderr[-4000:]
    shutil.rmtree(work / "blender_user" / "extensions" / ".cache", ignore_errors=True)
    return report


def test_install_runs_in_the_blender_and_python_it_names(installed):
    blender = installed["blender"]
    assert installed["blender_version"] == blender.bpy
    assert installed["python"] == blender.python


def test_extension_installs_and_enables_through_blender(installed):
    assert "install" not in installed["errors"], installed["errors"].get("install")
    assert {"__init__.py", "core", "pdic_addon", "blender_manifest.toml"} <= set(installed["installed_files"])
    assert "bl_ext.user_default.pdic" in installed["addons"]
    assert Path(installed["pdic_module"]).parent == Path(installed["repo_directory"]) / "pdic"


def test_bundled_wheels_are_unpacked_into_blenders_extension_site_packages(installed):
    assert "install" not in installed["errors"], installed["errors"].get("install")
    requirements = build_extension.BLENDER_PYTHONS[installed["python"]]
    for name, version in build_extension.pinned_versions(requirements=requirements).items():
        dist_info = f"{name}-{version}.dist-info"
        assert dist_info in installed["site_packages"], f"{dist_info} not unpacked: {installed['site_packages']}"
    assert not any(n.startswith("numpy") for n in installed["site_packages"]), "numpy must come from Blender"


def test_each_blender_unpacks_only_the_wheels_of_its_own_python(installed):
    """The zip holds cp311 and cp313 wheels; Blender (>= 4.2.13) unpacks only those of its Python."""
    assert "install" not in installed["errors"], installed["errors"].get("install")
    own = build_extension.python_tag(installed["python"])
    tags = installed["wheel_tags"]
    assert sorted(re.sub(r"-.*", "", d) for d in tags) == sorted(BUNDLED), tags
    for dist_info, wheel_tags in tags.items():
        assert wheel_tags and all(t.startswith(f"{own}-{own}-") for t in wheel_tags), (dist_info, wheel_tags)
    other = {"cp311": "313", "cp313": "311"}[own]
    compiled = [p.name for p in Path(installed["site_directory"]).rglob("*.so")]
    assert compiled and not any(f"cpython-{other}-" in name for name in compiled), \
        [n for n in compiled if f"cpython-{other}-" in n][:5]


def test_the_extensions_compiled_kernels_load_in_blender(installed):
    """The zig-built library of the zip passes its bit-for-bit check inside each Blender's own Python."""
    assert "bake" not in installed["errors"], installed["errors"].get("bake")
    assert installed["kernels"] == "compiled (pdic_native-linux-x64.so)", installed["kernels"]


def test_bake_imports_bundled_packages_from_the_extension_and_numpy_from_blender(installed):
    assert "bake" not in installed["errors"], installed["errors"].get("bake")
    site = Path(installed["site_directory"])
    for name in BUNDLED:
        assert site in Path(installed["module_files"][name]).parents, (name, installed["module_files"][name])
    assert site not in Path(installed["module_files"]["numpy"]).parents


def test_installed_extension_registers_bake_operator(installed):
    assert "bake" in installed["pdic_ops"], f"bpy.ops.pdic has {installed['pdic_ops']}\n{installed['log']}"


def test_installed_bake_operator_writes_sunlit_light_map(installed):
    assert "bake" not in installed["errors"], installed["errors"].get("bake")
    assert installed["bake_result"] == ["FINISHED"]
    image = installed["image"]
    assert image["size"] == [32, 32]
    assert image["finite"]
    assert image["covered_fraction"] > 0.3
    # A plane facing a sun of strength S holds E/pi = S/pi in every channel (white sun, no world, no bounce).
    expected = SUN_STRENGTH / 3.141592653589793
    for channel in image["mean_rgb_covered"]:
        assert channel == pytest.approx(expected, rel=0.1)
