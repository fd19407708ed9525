"""Build PDIC's compiled kernels (core/native/pdic_native.c) into core/native/pdic_native-<platform>.<ext>.

    python tools/build_native.py                      # this machine's platform, with its C compiler ($CC or cc)
    python tools/build_native.py --zig linux-x64 windows-x64 macos-arm64   # cross-built with zig

The library is optional (core/native_kernels.py falls back to numpy and says so), so a machine with
no C compiler still bakes, slower. zig comes from PyPI's ``ziglang`` package, installed on first use
into ``$PDIC_ZIG_CACHE`` or ``~/.cache/pdic/ziglang`` (a build tool, never part of the extension).
Every build uses -ffp-contract=off: a fused multiply-add would round differently from numpy, and the
kernels must give numpy's results to the bit. Linux builds target glibc 2.28 (Blender 4.2's minimum),
macOS builds 11.0.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _native_kernels():
    """core/native_kernels.py on its own (its platform names and paths; no package import, no library load)."""
    spec = importlib.util.spec_from_file_location("pdic_native_kernels_paths", ROOT / "core" / "native_kernels.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


_PATHS = _native_kernels()
library_path, platform_name = _PATHS.library_path, _PATHS.platform_name

SOURCE = ROOT / "core" / "native" / "pdic_native.c"
FLAGS = ["-O2", "-ffp-contract=off", "-fno-fast-math", "-std=c99", "-shared", "-g0"]
ZIG_TARGETS = {
    "linux-x64": "x86_64-linux-gnu.2.28",
    "windows-x64": "x86_64-windows-gnu",
    "macos-arm64": "aarch64-macos.11.0",
    "macos-x64": "x86_64-macos.11.0",
}
ZIGLANG = "ziglang==0.15.1"
"""The zig release these builds are made with (PyPI's ziglang wheel carries the whole toolchain: 94 MB,
380 MB installed, once per machine)."""


def up_to_date(out: Path) -> bool:
    return out.is_file() and out.stat().st_mtime >= SOURCE.stat().st_mtime


def platform_flags(name: str) -> list[str]:
    """Flags a shared library for Blender platform ``name`` needs beyond FLAGS."""
    return [] if name.startswith("windows") else ["-fPIC", "-fvisibility=hidden"]


def install(built: Path, out: Path) -> None:
    """Move a built library to ``out`` by a rename: a running process may have the old one loaded."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    shutil.copy2(built, tmp)
    os.replace(tmp, out)


def build_host(force: bool = False) -> Path | None:
    """This machine's library with its own C compiler; None (and a message) when there is none."""
    out = library_path()
    if up_to_date(out) and not force:
        return out
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if not cc:
        print(f"build_native: no C compiler (set CC): {out.name} not built; PDIC bakes with numpy kernels",
              file=sys.stderr)
        return None
    with tempfile.TemporaryDirectory() as tmp:
        built = Path(tmp) / out.name
        subprocess.run([cc, *FLAGS, *platform_flags(platform_name()), "-o", str(built), str(SOURCE), "-lm"],
                       check=True)
        install(built, out)
    print(f"build_native: {out.relative_to(ROOT)} ({out.stat().st_size:,} bytes, {Path(cc).name})", file=sys.stderr)
    return out


def zig_command() -> list[str]:
    """``python -m ziglang`` from a private install of the pinned ziglang wheel."""
    cache = Path(os.environ.get("PDIC_ZIG_CACHE", Path.home() / ".cache" / "pdic" / "ziglang"))
    if not (cache / "ziglang").is_dir():
        print(f"build_native: installing {ZIGLANG} into {cache} (once)", file=sys.stderr)
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--target", str(cache), ZIGLANG], check=True)
    return [sys.executable, "-c", f"import sys; sys.path.insert(0, {str(cache)!r}); import runpy; "
            "sys.argv[0] = 'ziglang'; runpy.run_module('ziglang', run_name='__main__')"]


def build_zig(name: str, folder: Path | None = None, force: bool = False) -> Path:
    """The library for Blender platform ``name``, cross-built with zig into ``folder`` (default core/native/)."""
    out = library_path(name) if folder is None else Path(folder) / library_path(name).name
    if up_to_date(out) and not force:
        return out
    extra = ["-s", *platform_flags(name)]
    if name.startswith("macos"):  # its id names itself, not the folder it was built in
        extra.append(f"-Wl,-install_name,@loader_path/{out.name}")
    with tempfile.TemporaryDirectory() as tmp:  # zig leaves an import library beside a .dll
        built = Path(tmp) / out.name
        cmd = [*zig_command(), "cc", "-target", ZIG_TARGETS[name], *FLAGS, *extra, "-o", str(built), str(SOURCE)]
        subprocess.run(cmd, check=True, cwd=tmp)
        install(built, out)
    print(f"build_native: {out.name} ({out.stat().st_size:,} bytes, zig {ZIG_TARGETS[name]})", file=sys.stderr)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--zig", nargs="+", metavar="PLATFORM", choices=sorted(ZIG_TARGETS),
                        help="cross-build these platforms with zig instead of the host's compiler")
    parser.add_argument("--force", action="store_true", help="rebuild even when the library is newer than its source")
    args = parser.parse_args(argv)
    if args.zig:
        for name in args.zig:
            build_zig(name, force=args.force)
    else:
        build_host(args.force)
    return 0


if __name__ == "__main__":
    sys.exit(main())
