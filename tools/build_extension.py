"""Build the PDIC Blender extension (.zip per platform) with Blender's own builder.

Steps:
1. Download (once, then from a cache outside git) the wheels of the bundled
   dependencies, scipy, embreex and xatlas, for each requested platform and for
   each Python Blender ships: cp311 (Blender 4.2 to 5.0) at the versions pinned in
   requirements.txt, cp313 (Blender 5.1 and 5.2) at those pinned in
   requirements-py313.txt. Blender unpacks only the wheels of its own Python
   (from 4.2.13 on; blender_manifest.toml's minimum). numpy is not bundled:
   Blender ships it.
2. Stage ``build/extension/`` with ``__init__.py``, ``core/``, ``pdic_addon/``,
   ``LICENSE`` (when present), ``wheels/`` and a copy of ``blender_manifest.toml``
   whose ``platforms`` and ``wheels`` list what was actually found; ``core/native/``
   gets the compiled kernels of each of those platforms, cross-built with zig
   (``tools/build_native.py``; zig is installed from PyPI's ziglang on first use).
3. Run ``blender_ext.py build --split-platforms`` (the builder inside the bpy
   wheel, the same code as ``blender --command extension build``) into ``dist/``,
   then ``blender_ext.py validate`` on every zip.

Usage::

    .venv/bin/python tools/build_extension.py                          # all platforms
    .venv/bin/python tools/build_extension.py --platform linux-x64     # one platform

Wheels are cached in ``$PDIC_WHEEL_CACHE`` or ``~/.cache/pdic/wheels/<platform>/``;
a platform for which some wheel does not exist on PyPI is left out (and said so).
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
import build_native  # noqa: E402

MANIFEST = ROOT / "blender_manifest.toml"
REQUIREMENTS = ROOT / "requirements.txt"

# The Pythons Blender bundles -> the requirements file pinning the wheels built for it:
# 3.11 in Blender 4.2 .. 5.0, 3.13 in Blender 5.1 and 5.2.
BLENDER_PYTHONS = {
    "3.11": ROOT / "requirements.txt",
    "3.13": ROOT / "requirements-py313.txt",
}
# Bundled into the extension; numpy is left out on purpose (Blender ships it).
BUNDLED = ("scipy", "embreex", "xatlas")
# Blender platform -> pip platform tags accepted for it, most compatible first
# (Blender 4.2+ needs glibc 2.28 on Linux and macOS 11.2 on Apple silicon).
PLATFORM_TAGS = {
    "linux-x64": ("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64"),
    "windows-x64": ("win_amd64",),
    "macos-arm64": ("macosx_11_0_arm64", "macosx_12_0_arm64", "macosx_13_0_arm64", "macosx_14_0_arm64"),
}
# What goes into the extension besides the manifest and wheels.
PACKAGE_PATHS = ("__init__.py", "core", "pdic_addon", "LICENSE")


class BuildError(RuntimeError):
    """A build step failed; the message says which and why."""


def default_wheel_cache() -> Path:
    """Where downloaded wheels are kept between builds (outside git, shared by clones)."""
    if env := os.environ.get("PDIC_WHEEL_CACHE"):
        return Path(env)
    return Path.home() / ".cache" / "pdic" / "wheels"


def bpy_scripts_dir() -> Path:
    """``bpy/<version>/scripts`` inside the installed bpy wheel, found without importing bpy."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise BuildError("the bpy wheel is not installed in this interpreter: run tools/setup.sh and use .venv/bin/python")
    bpy_dir = Path(list(spec.submodule_search_locations)[0])
    found = sorted(bpy_dir.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not found:
        raise BuildError(f"no bl_pkg/cli/blender_ext.py under {bpy_dir}")
    return found[-1].parents[3]


def blender_ext_path() -> Path:
    """Blender's extension command-line tool (build/validate/install-files); runs with plain Python."""
    return bpy_scripts_dir() / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"


def valid_tags_path() -> Path:
    """The tag list Blender validates against in ``blender --command extension``."""
    return bpy_scripts_dir() / "modules" / "_bpy_internal" / "extensions" / "tags.py"


def run_blender_ext(*args: str) -> subprocess.CompletedProcess:
    """Run ``blender_ext.py`` with this interpreter; raises BuildError with its output on failure."""
    cmd = [sys.executable, str(blender_ext_path()), *args]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise BuildError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout}{proc.stderr}")
    return proc


def validate(path: Path) -> str:
    """Validate a source directory or a built zip with Blender's validator (strict tags); returns its output."""
    return run_blender_ext("validate", "--valid-tags", str(valid_tags_path()), str(path)).stdout.strip()


def pinned_versions(names=BUNDLED, requirements: Path = REQUIREMENTS) -> dict[str, str]:
    """``{name: version}`` of ``names`` as pinned (``name==version``) in requirements.txt."""
    pins = {}
    for line in requirements.read_text().splitlines():
        m = re.match(r"^\s*([A-Za-z0-9_.\-]+)\s*==\s*([^\s;#]+)", line)
        if m:
            pins[m.group(1).lower()] = m.group(2)
    missing = [n for n in names if n.lower() not in pins]
    if missing:
        raise BuildError(f"{requirements} pins no version for {', '.join(missing)} (expected 'name==version')")
    return {n: pins[n.lower()] for n in names}


def python_tag(python: str) -> str:
    """The wheel tag of CPython ``python``: ``"3.13"`` -> ``"cp313"``."""
    return "cp" + python.replace(".", "")


def _cached_wheel(directory: Path, name: str, version: str, python: str) -> Path | None:
    stem = re.sub(r"[-_.]+", "_", name).lower()
    pattern = f"{stem}-{version}-{python_tag(python)}-*.whl"
    found = sorted(directory.glob(pattern)) if directory.is_dir() else []
    return found[0] if found else None


def fetch_wheels(platform: str, versions: dict[str, str], cache: Path, python: str) -> tuple[list[Path], list[str]]:
    """Wheels of ``versions`` for Blender ``platform`` and CPython ``python`` (cached, else ``pip download``).

    Returns (wheels found, names with no wheel for this platform and Python on the index).
    """
    directory = cache / platform
    wheels, missing = [], []
    for name, version in versions.items():
        wheel = _cached_wheel(directory, name, version, python)
        if wheel is None:
            # Download into a private folder, then move into the cache: a concurrent
            # build never sees a half-written wheel.
            directory.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory(dir=directory, prefix=".download-") as tmp:
                cmd = [
                    sys.executable, "-m", "pip", "download", "--disable-pip-version-check", "-q",
                    "--only-binary=:all:", "--no-deps",
                    "--python-version", python, "--implementation", "cp",
                    *[arg for tag in PLATFORM_TAGS[platform] for arg in ("--platform", tag)],
                    "-d", tmp, f"{name}=={version}",
                ]
                print(f"download: {name}=={version} for {platform}, {python_tag(python)}", flush=True)
                proc = subprocess.run(cmd, capture_output=True, text=True)
                if (fetched := _cached_wheel(Path(tmp), name, version, python)) is not None:
                    os.replace(fetched, directory / fetched.name)
            wheel = _cached_wheel(directory, name, version, python)
            if proc.returncode != 0 or wheel is None:
                tail = "\n".join((proc.stdout + proc.stderr).strip().splitlines()[-3:])
                print(f"  no wheel: {name}=={version} for {platform}, {python_tag(python)}: {tail}", flush=True)
                missing.append(name)
                continue
        wheels.append(wheel)
    return wheels, missing


def manifest_with_wheels(text: str, platforms: list[str], wheels: list[str]) -> str:
    """The source manifest with ``platforms`` replaced and a ``wheels`` list added (before any table)."""
    platforms_line = "platforms = [" + ", ".join(f'"{p}"' for p in platforms) + "]"
    wheels_block = "wheels = [\n" + "".join(f'  "./wheels/{w}",\n' for w in wheels) + "]"
    if re.search(r"^wheels\s*=", text, flags=re.M):
        raise BuildError(f"{MANIFEST.name} must not list wheels itself: the build adds them")
    new, n = re.subn(r"^platforms\s*=\s*\[[^\]]*\]", platforms_line + "\n" + wheels_block, text, count=1, flags=re.M)
    if n != 1:
        raise BuildError(f"{MANIFEST.name} has no top-level 'platforms = [...]' line to fill in")
    return new


def stage(staging: Path, wheels: list[Path], platforms: list[str]) -> Path:
    """Fill ``staging`` with the package, the wheels and the generated manifest."""
    if staging.exists():
        shutil.rmtree(staging)
    staging.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", ".*")
    for rel in PACKAGE_PATHS:
        src = ROOT / rel
        if src.is_dir():
            shutil.copytree(src, staging / rel, ignore=ignore)
        elif src.is_file():
            shutil.copy2(src, staging / rel)
        elif rel != "LICENSE":
            raise BuildError(f"missing {src}: the extension needs it")
    stage_native(staging / "core" / "native", platforms)
    (staging / "wheels").mkdir()
    for wheel in wheels:
        shutil.copy2(wheel, staging / "wheels" / wheel.name)
    text = manifest_with_wheels(MANIFEST.read_text(), platforms, sorted(w.name for w in wheels))
    (staging / MANIFEST.name).write_text(text)
    return staging


def stage_native(folder: Path, platforms: list[str]) -> None:
    """The compiled kernels of Equation 3 (core/native_kernels.py) for each platform, cross-built with zig
    from core/native/pdic_native.c (their source ships beside them); whatever the checkout had built for
    itself is left out."""
    for old in folder.glob("pdic_native-*"):
        old.unlink()
    for platform in platforms:
        try:
            build_native.build_zig(platform, folder, force=True)
        except (OSError, subprocess.CalledProcessError) as ex:
            raise BuildError(f"could not build the compiled kernels for {platform} with zig: {ex}") from ex


def build(platforms: list[str], dist: Path, cache: Path, staging: Path) -> list[Path]:
    """Build one zip per platform that has every bundled wheel for every Blender Python; returns their paths."""
    versions = {python: pinned_versions(requirements=path) for python, path in BLENDER_PYTHONS.items()}
    ready, wheels = [], {}
    for platform in platforms:
        t0 = time.perf_counter()
        found, missing = [], []
        for python, pins in versions.items():
            have, lack = fetch_wheels(platform, pins, cache, python)
            found += have
            missing += [f"{name} ({python_tag(python)})" for name in lack]
        if missing:
            print(f"skip {platform}: no wheel for {', '.join(missing)}", flush=True)
            continue
        print(f"wheels {platform}: {', '.join(w.name for w in found)} ({time.perf_counter() - t0:.1f} s)", flush=True)
        ready.append(platform)
        wheels[platform] = found
    if not ready:
        raise BuildError(f"no platform among {', '.join(platforms)} has all of {', '.join(BUNDLED)}")

    dist.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    for platform in ready:  # staged one platform at a time: each zip holds its own compiled kernels only
        stage(staging, wheels[platform], [platform])
        run_blender_ext(
            "build", "--split-platforms", "--valid-tags", str(valid_tags_path()),
            "--source-dir", str(staging), "--output-dir", str(dist),
        )
    version = re.search(r'^version\s*=\s*"([^"]+)"', MANIFEST.read_text(), flags=re.M).group(1)
    zips = [dist / f"pdic-{version}-{p.replace('-', '_')}.zip" for p in ready]
    for z in zips:
        if not z.is_file():
            raise BuildError(f"Blender's builder did not write {z}")
        validate(z)
        print(f"built {z} ({z.stat().st_size / 2**20:.1f} MiB)", flush=True)
    print(f"build+validate {time.perf_counter() - t0:.1f} s", flush=True)
    return zips


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--platform", action="append", choices=sorted(PLATFORM_TAGS),
                        help="build only this platform (repeatable; default: all)")
    parser.add_argument("--dist", type=Path, default=ROOT / "dist", help="output folder (default: dist/)")
    parser.add_argument("--wheel-cache", type=Path, default=None,
                        help="downloaded wheels (default: $PDIC_WHEEL_CACHE or ~/.cache/pdic/wheels)")
    parser.add_argument("--staging", type=Path, default=ROOT / "build" / "extension",
                        help="staging folder, recreated on every build (default: build/extension)")
    args = parser.parse_args(argv)
    try:
        build(args.platform or list(PLATFORM_TAGS), args.dist.resolve(),
              (args.wheel_cache or default_wheel_cache()).resolve(), args.staging.resolve())
    except BuildError as ex:
        print(f"build_extension: error: {ex}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
