"""The bpy border (STYLE.md, principle 1): ``core`` runs without Blender.

Each check runs in a fresh interpreter with only the repository root on the
path, so nothing the test session (or conftest) already imported can hide an
import of bpy.
"""
from __future__ import annotations

import ast
import json
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "core"
# Modules that exist only inside Blender.
BLENDER_MODULES = ("bpy", "bpy_extras", "bpy_types", "mathutils", "bmesh", "gpu", "gpu_extras", "aud", "bl_math",
                   "idprop", "imbuf", "freestyle", "addon_utils")


def run_fresh(code: str) -> dict:
    """Run ``code`` in a fresh interpreter (cwd = repo root, root on sys.path); return the JSON it prints last."""
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, f"fresh interpreter failed:\n{proc.stdout}\n{proc.stderr}"
    return json.loads(proc.stdout.strip().splitlines()[-1])


# A meta-path finder that refuses Blender's modules and records who asked, so
# an import of bpy wrapped in try/except still shows up.
GUARD = f"""
import json, sys, traceback
sys.path.insert(0, {str(ROOT)!r})
BLOCKED = {BLENDER_MODULES!r}
attempts = []

class BlockBlender:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            frames = [f for f in traceback.extract_stack()[:-1] if "importlib" not in f.filename]
            attempts.append({{"module": name, "from": f"{{frames[-1].filename}}:{{frames[-1].lineno}}" if frames else "?"}})
            raise ImportError(f"{{name}} is blocked: core must not import Blender modules")
        return None

sys.meta_path.insert(0, BlockBlender())
"""


def test_importing_core_leaves_bpy_unloaded():
    report = run_fresh("""
        import json, sys
        sys.path.insert(0, %r)
        import core
        print(json.dumps({"core_file": core.__file__,
                          "blender": sorted(m for m in sys.modules if m.split(".")[0] in %r)}))
    """ % (str(ROOT), BLENDER_MODULES))
    assert Path(report["core_file"]).resolve() == (CORE / "__init__.py").resolve()
    assert report["blender"] == [], f"'import core' loaded Blender modules: {report['blender']}"


def test_every_core_module_imports_without_blender():
    report = run_fresh(GUARD + """
import importlib, pkgutil
import core
imported, failed = [], {}
for info in pkgutil.walk_packages(core.__path__, "core."):
    try:
        importlib.import_module(info.name)
        imported.append(info.name)
    except Exception as ex:
        failed[info.name] = f"{type(ex).__name__}: {ex}"
loaded = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
print(json.dumps({"imported": imported, "failed": failed, "attempts": attempts, "loaded": loaded}))
""")
    on_disk = {f"core.{p.stem}" for p in CORE.glob("*.py") if p.stem != "__init__"}
    assert {"core.rays", "core.scene", "core.settings", "core.executor"} <= on_disk
    assert report["attempts"] == [], f"core modules tried to import Blender modules: {report['attempts']}"
    assert report["failed"] == {}, f"core modules failed to import without Blender: {report['failed']}"
    assert on_disk <= set(report["imported"]), f"not walked: {sorted(on_disk - set(report['imported']))}"
    assert report["loaded"] == []


def test_no_core_source_imports_blender_modules():
    """Also catches imports inside functions, which only run during a bake."""
    offenders = []
    for path in sorted(CORE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                if name.split(".")[0] in BLENDER_MODULES:
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} imports {name}")
    assert offenders == [], "core/ must never import Blender modules:\n" + "\n".join(offenders)
