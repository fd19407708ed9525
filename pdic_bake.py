"""Headless PDIC bake.

Inside Blender::

    blender --background scene.blend --python pdic_bake.py -- --output maps/ --quality PREVIEW

With the bpy wheel (plain Python)::

    .venv/bin/python pdic_bake.py --blend scene.blend --output maps/ --preview-png look.png

Bakes the scene's light maps (all bakeable meshes, or ``--objects``), writes
``<blend>.PDIC_<object>.exr`` and ``pdic_manifest.json`` into the output folder and
prints per-stage times, texel counts and output paths. The .blend on disk is
never modified; ``--save-blend PATH`` saves the baked scene (UV maps, images,
material copies) as a new file, never the input. On error the message names
the culprit and the exit code is 1 (2 for bad arguments); Ctrl+C cancels the
bake, leaves every output as it was and exits with 130. ``--scheduler tcp://host:port``
(or ``local:N``) runs the heavy stages on a Dask cluster (README, "Baking on a Dask cluster").
"""
from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import time
from dataclasses import replace

INSIDE_BLENDER = "bpy" in sys.modules  # the Blender binary imports bpy before running scripts
EXIT_ERROR, EXIT_USAGE, EXIT_INTERRUPTED = 1, 2, 130


class ScriptError(Exception):
    """An error reported as ``pdic_bake: error: ...`` with exit code 1."""


class UsageError(ScriptError):
    """Arguments that cannot work together (found after loading the .blend): exit code 2."""


def script_args(argv: list[str]) -> list[str]:
    if "--" in argv:
        return argv[argv.index("--") + 1:]
    return [] if INSIDE_BLENDER else argv[1:]


def parse_args(args: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="pdic_bake", description="Bake PDIC light maps without the UI.")
    p.add_argument("--blend", help="the .blend to bake (default: the file Blender opened)")
    p.add_argument("--output", metavar="DIR", help="folder for images and manifest (default: the scene's "
                                                   "PDIC output folder, //pdic_lightmaps/)")
    p.add_argument("--objects", nargs="+", metavar="NAME", help="objects to bake (default: every bakeable mesh)")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--resolution", type=int, metavar="N", help="light-map width and height for every object")
    size.add_argument("--texel-density", type=float, metavar="D", help="texels per scene unit")
    p.add_argument("--uv-map", metavar="NAME",
                   help="bake into each object's UV map NAME as it is laid out (your own light-map UVs; objects "
                        "without one are unwrapped by PDIC)")
    p.add_argument("--passes", default=None, help="comma-separated: direct,indirect (default: the scene's)")
    p.add_argument("--quality", type=str.upper, choices=("PREVIEW", "FINAL", "CUSTOM"))
    p.add_argument("--photons", type=int)
    p.add_argument("--direct-samples", type=int, metavar="N",
                   help="shadow rays per texel sample toward each soft light (the sky, area lights)")
    p.add_argument("--seed", type=int)
    p.add_argument("--threads", type=int, help="worker threads (0 = all cores)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the heavy stages on a Dask cluster: tcp://host:port of a running 'dask scheduler', "
                        "or local:N for N single-thread worker processes here (needs dask and distributed)")
    p.add_argument("--format", choices=("EXR_HALF", "EXR_FLOAT"), help="image format")
    p.add_argument("--save-blend", metavar="PATH", help="save the baked scene as this .blend")
    p.add_argument("--preview-png", metavar="PATH", help="render the scene camera's view lit by the light maps")
    p.add_argument("--preview-width", type=int, default=480, metavar="PX", help="preview width (default 480)")
    p.add_argument("--exposure", type=float, default=0.0, help="preview exposure in stops")
    p.add_argument("--atlas-size", type=int, metavar="N", help="pack all objects into shared NxN atlases "
                                                                  "(0 = one map per object; default: the scene's)")
    p.add_argument("--export-glb", metavar="PATH", help="export the baked scene as .glb with its light maps")
    ns = p.parse_args(args)
    if ns.resolution is not None and ns.resolution < 8:
        p.error(f"--resolution {ns.resolution}: must be at least 8")
    if ns.texel_density is not None and not (ns.texel_density > 0 and math.isfinite(ns.texel_density)):
        p.error(f"--texel-density {ns.texel_density}: must be a positive finite number of texels per unit")
    for option, value, least in (("--photons", ns.photons, 0), ("--seed", ns.seed, 0), ("--threads", ns.threads, 0),
                                 ("--preview-width", ns.preview_width, 8), ("--direct-samples", ns.direct_samples, 1)):
        if value is not None and value < least:
            p.error(f"{option} {value}: must be at least {least}")
    if ns.scheduler is not None and not scheduler_address_ok(ns.scheduler):
        p.error(f"--scheduler {ns.scheduler!r}: use tcp://host:port (or tls://, ws://, wss://) or local:N with N >= 1")
    if not math.isfinite(ns.exposure):
        p.error(f"--exposure {ns.exposure}: must be finite")
    if ns.passes is not None:
        passes = {s.strip().lower() for s in ns.passes.split(",") if s.strip()}
        if not passes or passes - {"direct", "indirect"}:
            p.error(f"--passes {ns.passes!r}: use direct, indirect or direct,indirect")
        ns.passes = passes
    return ns


def scheduler_address_ok(address: str) -> bool:
    """``tcp://host:port`` (or tls, ws, wss) or ``local:N`` with N >= 1."""
    if address.startswith("local:"):
        return address[6:].isdigit() and int(address[6:]) >= 1
    protocol, _, rest = address.partition("://")
    return protocol in ("tcp", "tls", "ws", "wss") and bool(rest)


def load_package():
    """The PDIC package: this checkout (pdic_bootstrap) or the installed extension."""
    here = os.path.dirname(os.path.abspath(__file__))
    if os.path.isfile(os.path.join(here, "pdic_bootstrap.py")) and os.path.isdir(os.path.join(here, "core")):
        sys.path.insert(0, here)
        import pdic_bootstrap

        return pdic_bootstrap.load()
    import importlib

    import addon_utils
    import bpy

    for module in addon_utils.modules():
        if module.__name__.endswith(".pdic") or module.__name__ == "pdic":
            if module.__name__ not in bpy.context.preferences.addons:
                addon_utils.enable(module.__name__, default_set=False)
            return importlib.import_module(module.__name__)
    raise ScriptError("PDIC is neither next to this script nor installed as a Blender extension")


def open_blend(bpy, path: str | None) -> None:
    if path is None:
        return
    if not os.path.isfile(path):
        raise ScriptError(f"no such .blend file: {path!r}")
    try:
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(path), load_ui=False)
    except RuntimeError as e:
        raise ScriptError(f"cannot open {path!r}: {e}") from e


def build_settings(pdic, props, args):
    from_props = sub(pdic, "pdic_addon.properties").to_settings
    settings = from_props(props, quality=args.quality)
    overrides = {}
    if args.photons is not None:
        overrides["photons"] = args.photons
    if args.direct_samples is not None:
        overrides["direct_samples"] = args.direct_samples
    if args.seed is not None:
        overrides["seed"] = args.seed
    if args.threads is not None:
        overrides["threads"] = args.threads
    if args.resolution is not None:
        overrides.update(default_resolution=args.resolution, texel_density=0.0)
    if args.texel_density is not None:
        overrides["texel_density"] = args.texel_density
    if args.passes is not None:
        overrides.update(direct="direct" in args.passes, indirect="indirect" in args.passes)
    try:
        return replace(settings, **overrides)
    except ValueError as e:
        raise ScriptError(str(e)) from e


def output_folder(bpy, props, args) -> str:
    if args.output:
        return os.path.abspath(os.path.expanduser(args.output))
    folder = props.output_folder
    if folder.startswith("//") and not bpy.data.filepath:
        if args.save_blend:
            return os.path.join(os.path.dirname(os.path.abspath(args.save_blend)), folder[2:])
        raise ScriptError("the scene is not saved, so the output folder "
                          f"{folder!r} has no place: pass --output DIR or --save-blend PATH")
    return folder


def sub(pdic, name: str):
    """Submodule ``name`` of the PDIC package, whatever the package is called (pdic, bl_ext.*.pdic)."""
    import importlib

    return importlib.import_module(f"{pdic.__name__}.{name}")


def preview_camera(bpy, pdic, scene_core):
    """core.camera_render.Camera for the scene camera, in the bake's scene-local space, and its aspect."""
    import numpy as np

    Camera = sub(pdic, "core.camera_render").Camera
    cam = bpy.context.scene.camera
    if cam is None or cam.type != "CAMERA":
        raise UsageError("--preview-png needs a scene camera (Scene > Camera is empty); nothing was baked")
    frame = np.array([tuple(v) for v in cam.data.view_frame(scene=bpy.context.scene)])
    m = np.array(cam.matrix_world, np.float64)
    rotation = m[:3, :3] / np.linalg.norm(m[:3, :3], axis=0)
    scale = np.linalg.norm(m[:3, :3], axis=0)
    ortho = cam.data.type == "ORTHO"
    half = np.abs(frame[:, :2]).max(axis=0)
    if ortho:
        half = half * scale[:2]
    else:
        half = half / np.abs(frame[0, 2])
    if scene_core is None:  # only checking that there is a camera
        return None, 0.0
    r = bpy.context.scene.render
    aspect = (r.resolution_y * r.pixel_aspect_y) / max(r.resolution_x * r.pixel_aspect_x, 1)
    return Camera(m[:3, 3] - scene_core.origin_world, rotation, float(half[0]), float(half[1]), ortho), aspect


def main(argv: list[str]) -> int:
    try:
        args = parse_args(script_args(argv))
    except SystemExit as e:  # argparse printed the usage error
        return EXIT_USAGE if e.code else 0
    try:
        return bake(args)
    except ScriptError as e:
        print(f"pdic_bake: error: {e}", file=sys.stderr)
        return EXIT_USAGE if isinstance(e, UsageError) else EXIT_ERROR
    except KeyboardInterrupt:  # a second Ctrl+C, or one outside the bake: the job has rolled back
        print("pdic_bake: interrupted; outputs left as they were", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as e:  # a bug: the job rolled back; the .blend on disk was never written
        import traceback

        traceback.print_exc()
        print(f"pdic_bake: internal error: {type(e).__name__}: {e}", file=sys.stderr)
        return EXIT_ERROR


def check_save_path(bpy, args) -> None:
    """--save-blend must not be the .blend being baked (by any name: symlink, relative path, hard link)."""
    if not args.save_blend:
        return
    target = os.path.realpath(os.path.abspath(os.path.expanduser(args.save_blend)))
    source = bpy.data.filepath and os.path.realpath(bpy.data.filepath)
    same = bool(source) and (target == source or (os.path.exists(target) and os.path.samefile(target, source)))
    if same:
        raise UsageError(f"--save-blend {args.save_blend!r} is the .blend being baked ({bpy.data.filepath}); "
                          f"the input is never overwritten: save to another path")
    if os.path.isdir(target):
        raise UsageError(f"--save-blend {args.save_blend!r} is a folder; give a .blend file path")


def chosen_objects(bpy, args):
    if not args.objects:
        return None
    missing = [n for n in args.objects if n not in bpy.data.objects]
    if missing:
        raise ScriptError(f"no object named {', '.join(map(repr, missing))} in {bpy.data.filepath or 'the scene'}")
    return [bpy.data.objects[n] for n in args.objects]


def use_uv_map(bpy, objects, name: str) -> None:
    """Set Light-Map UVs to ``name`` on the meshes to bake that have a UV map of that name."""
    candidates = objects if objects is not None else [o for o in bpy.context.view_layer.objects if o.type == "MESH"]
    having = [o for o in candidates if o.type == "MESH" and name in o.data.uv_layers]
    if not having:
        raise ScriptError(f"--uv-map {name!r}: no mesh to bake has a UV map of that name")
    for obj in having:
        obj.pdic.uv_map = name
    others = len([o for o in candidates if o.type == "MESH"]) - len(having)
    print(f"pdic_bake: {len(having)} objects bake into their UV map {name!r}"
          + (f"; {others} without one are unwrapped" if others else ""))


def cancel_on_sigint(progress):
    """Ctrl+C cancels the bake (it stops at its next progress check and rolls back); a second one
    interrupts at once. Importing bpy replaces Python's SIGINT handler: this puts one back."""

    def handler(signum, frame):
        if progress.cancel_requested.is_set():
            raise KeyboardInterrupt
        print("pdic_bake: cancelling (Ctrl+C again to stop at once)...", file=sys.stderr, flush=True)
        progress.cancel()

    signal.signal(signal.SIGINT, handler)


def bake(args) -> int:
    import bpy

    pdic = load_package()
    open_blend(bpy, args.blend)
    executor = sub(pdic, "core.executor")
    job_module = sub(pdic, "pdic_addon.job")
    progress = executor.Progress(stage_printer())
    cancel_on_sigint(progress)

    if not hasattr(bpy.types.Scene, "pdic"):
        sub(pdic, "pdic_addon").register()
    scene = bpy.context.scene
    props = scene.pdic
    settings = build_settings(pdic, props, args)
    objects = chosen_objects(bpy, args)
    check_save_path(bpy, args)
    if args.uv_map:
        use_uv_map(bpy, objects, args.uv_map)
    if args.preview_png:  # before anything is written
        preview_camera(bpy, pdic, None)
    folder = output_folder(bpy, props, args)
    print(f"pdic_bake: {bpy.data.filepath or '(unsaved scene)'}: quality {settings.quality}, "
          f"{settings.photons} photons, seed {settings.seed}, passes "
          f"{'+'.join(p for p in ('direct', 'indirect') if getattr(settings, p))}")

    job = job_module.BakeJob(bpy.context, settings, objects=objects, output_folder=folder,
                             image_format=args.format or props.image_format, atlas_size=args.atlas_size,
                             scheduler=args.scheduler)
    start = time.perf_counter()
    try:
        report = job_module.JobRunner(job, progress).run()
    except executor.Cancelled:
        print("pdic_bake: cancelled; outputs left as they were", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (job_module.BakeError, sub(pdic, "core.scene").SceneError) as e:
        raise ScriptError(str(e)) from e
    print_report(report, time.perf_counter() - start)
    if args.preview_png:
        write_preview(bpy, pdic, job, args)
    if args.export_glb:
        try:
            print(f"glb: {sub(pdic, 'pdic_addon.gltf_export').export_glb(bpy.context, os.path.abspath(args.export_glb))}")
        except ValueError as e:
            raise ScriptError(str(e)) from e
    if args.save_blend:
        path = os.path.abspath(args.save_blend)
        try:
            bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
        except RuntimeError as e:
            raise ScriptError(f"cannot save {path!r}: {e}") from e
        print(f"saved: {path}")
    return 0


def stage_printer():
    last = [None]

    def on_progress(stage, fraction, eta):
        if stage != last[0]:
            last[0] = stage
            print(f"  .. {stage}", flush=True)

    return on_progress


def print_report(report, total: float) -> None:
    print("stage times (s):")
    for stage, seconds in report.stats.get("seconds", {}).items():
        print(f"  {stage:<24s} {seconds:8.3f}")
    print(f"  {'total':<24s} {total:8.3f}")
    if "kernels" in report.stats:
        print(f"kernels: {report.stats['kernels']}")
    print("light maps:")
    for e in report.objects:
        where = os.path.join(str(report.output.directory), e["image"]) if e["image"] else "(packed)"
        print(f"  {e['name']:<24s} {e['width']}x{e['height']} texels, {e['texels']} covered -> {where}")
    for w in report.warnings:
        print(f"warning: {w}")
    if report.manifest_path is not None:
        print(f"manifest: {report.manifest_path}")


def write_preview(bpy, pdic, job, args) -> None:
    preview = sub(pdic, "core.camera_render")
    start = time.perf_counter()
    camera, aspect = preview_camera(bpy, pdic, job.extraction.scene)
    width = max(int(args.preview_width), 8)
    height = max(int(round(width * aspect)), 8)
    radiance = preview.render_preview(job.extraction.scene, job.result.lightmaps, camera, width, height)
    path = os.path.abspath(args.preview_png)
    try:
        preview.write_png(path, preview.tone_map(radiance, args.exposure))
    except OSError as e:
        raise ScriptError(f"cannot write preview {path!r}: {e.strerror}") from e
    print(f"preview: {path} ({width}x{height}, {time.perf_counter() - start:.2f} s)")


if __name__ == "__main__":
    code = main(sys.argv)
    sys.stdout.flush()
    if code or not INSIDE_BLENDER:
        sys.exit(code)
