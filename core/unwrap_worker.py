"""Child process of :func:`core.unwrap.unwrap` and :func:`core.atlas.pack_atlases`: run xatlas on
arrays in a folder.

Usage: ``python -I unwrap_worker.py FOLDER``. Reads ``FOLDER/request.json`` (the parent's
``sys_path``, ``task`` and its scalars) and ``FOLDER/input.npz``; writes ``output.npz`` and then
``status.json`` (the scalar results, or ``error`` and ``message``). A crash leaves no
``status.json``, which is how the parent tells a crash from an answer.

* task ``unwrap`` (the default): resolution, padding, max_resolution, variant; arrays positions,
  triangles, optional polygon -> uv, chart (:func:`core.xatlas_charts.layout`).
* task ``atlas``: :func:`core.atlas.pack_request` / :func:`core.atlas.layout_answer` say what goes
  in and out (every object's charts -> their placements in the atlases).
"""
from __future__ import annotations

import importlib
import importlib.util
import json
import os
import sys
from pathlib import Path

CORE = "_pdic_unwrap_core"


def _core_module(name: str):
    """``core.<name>`` loaded from this file's folder under a private package name (the
    add-on's own package name is not importable from a plain interpreter)."""
    if CORE not in sys.modules:
        folder = Path(__file__).resolve().parent
        spec = importlib.util.spec_from_file_location(CORE, folder / "__init__.py",
                                                      submodule_search_locations=[str(folder)])
        package = importlib.util.module_from_spec(spec)
        sys.modules[CORE] = package
        spec.loader.exec_module(package)
    return importlib.import_module(f"{CORE}.{name}")


def main(folder: Path) -> None:
    request = json.loads((folder / "request.json").read_text())
    sys.path[:0] = [s for s in request.get("sys_path", []) if s not in sys.path]
    import numpy as np

    if request.get("task") == "atlas":
        _pack_atlases(folder, request)
        return
    charts = _core_module("xatlas_charts")
    with np.load(folder / "input.npz", allow_pickle=False) as data:
        p, tri = data["positions"], data["triangles"]
        poly = data["polygon"] if "polygon" in data.files else None
    try:
        out = charts.layout(p, tri, int(request["resolution"]), int(request["padding"]), poly,
                            int(request["max_resolution"]), int(request["variant"]),
                            float(request.get("texels_per_unit", 0.0)))
    except charts.PackError as e:
        status = dict(error="PackError", message=str(e), minimum=e.minimum)
    except ValueError as e:
        status = dict(error="ValueError", message=str(e))
    except Exception as e:  # reported to the parent, which names the object
        status = dict(error=type(e).__name__, message=str(e))
    else:
        np.savez(folder / "output.npz", uv=out.pop("uv"), chart=out.pop("chart"))
        status = out
    _answer(folder, status)


def _pack_atlases(folder: Path, request: dict) -> None:
    import numpy as np

    atlas = _core_module("atlas")
    with np.load(folder / "input.npz", allow_pickle=False) as data:
        inputs = atlas.inputs_from_request(request, data)
    try:
        layout = atlas.pack_atlases(inputs, int(request["size"]), int(request["padding"]),
                                    float(request["texels_per_unit"]), in_process=True)
    except ValueError as e:  # an object that does not fit: the message names it
        status = dict(error="ValueError", message=str(e))
    except Exception as e:
        status = dict(error=type(e).__name__, message=str(e))
    else:
        status, arrays = atlas.layout_answer(layout)
        np.savez(folder / "output.npz", **arrays)
    _answer(folder, status)


def _answer(folder: Path, status: dict) -> None:
    (folder / "status.tmp").write_text(json.dumps(status))
    (folder / "status.tmp").replace(folder / "status.json")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
    # The answer is on disk: leave without tearing xatlas down at interpreter exit (its
    # destructor once hung waiting for its worker threads).
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)
