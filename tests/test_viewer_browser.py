"""The exported .glb in a real browser: web/ (three.js) in headless Debian Chromium via Playwright
shows the same picture as PDIC's own camera render of the baked light maps.

Needs ``bash tools/setup_web.sh`` (apt chromium, ``npm ci`` in web/); without it these tests FAIL
naming that script - a missing browser is never a silent skip.
"""
from __future__ import annotations

import functools
import http.server
import json
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
WEB = ROOT / "web"
CHROMIUM = Path("/usr/bin/chromium")
WIDTH = 320
MAX_MEAN_RELATIVE_DIFFERENCE = 0.03


def require_web_setup() -> None:
    missing = [what for what, ok in (("/usr/bin/chromium", CHROMIUM.exists()),
                                     ("web/node_modules/three", (WEB / "node_modules" / "three").is_dir()),
                                     ("web/node_modules/playwright-core",
                                      (WEB / "node_modules" / "playwright-core").is_dir()),
                                     ("web/.pdic-web-ready", (WEB / ".pdic-web-ready").is_file()))
               if not ok]
    if missing:
        pytest.fail(f"browser test set-up did not run (missing {', '.join(missing)}): run `bash tools/setup_web.sh`")


class _Server:
    """web/ and one model.glb on 127.0.0.1 (an OS-chosen port), in a thread."""

    def __init__(self, glb: Path):
        glb_bytes = glb.read_bytes()

        class Handler(http.server.SimpleHTTPRequestHandler):
            def do_GET(self):
                if self.path.split("?")[0] == "/model.glb":
                    self.send_response(200)
                    self.send_header("Content-Type", "model/gltf-binary")
                    self.send_header("Content-Length", str(len(glb_bytes)))
                    self.end_headers()
                    self.wfile.write(glb_bytes)
                    return
                super().do_GET()

            def log_message(self, *args):
                pass

        handler = functools.partial(Handler, directory=str(WEB))
        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)

    def __enter__(self):
        self.thread.start()
        return f"http://127.0.0.1:{self.httpd.server_address[1]}"

    def __exit__(self, *exc):
        self.httpd.shutdown()
        self.httpd.server_close()


def screenshot(glb: Path, out: Path, width: int, height: int) -> dict:
    with _Server(glb) as base:
        url = f"{base}/index.html?model=model.glb&w={width}&h={height}&ui=0&mips=0"
        run = subprocess.run(["node", str(WEB / "screenshot.mjs"), url, str(out), str(width), str(height)],
                             cwd=WEB, capture_output=True, text=True, timeout=300)
    lines = [l for l in run.stdout.splitlines() if l.startswith("{")]
    state = json.loads(lines[-1]) if lines else {"ok": False, "error": run.stderr[-2000:]}
    assert run.returncode == 0 and state["ok"], f"viewer failed: {state}"
    return state


def read_png(bpy, path: Path) -> np.ndarray:
    """(H, W, 3) float 0..1 display values (sRGB bytes / 255), row 0 = top."""
    image = bpy.data.images.load(str(path), check_existing=False)
    try:
        image.colorspace_settings.name = "Non-Color"
        w, h = image.size
        px = np.empty(w * h * 4, np.float32)
        image.pixels.foreach_get(px)
        return px.reshape(h, w, 4)[::-1, :, :3].astype(np.float64)
    finally:
        bpy.data.images.remove(image)


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def quantised_lightmaps(job) -> dict:
    """Target name -> light map as the .glb carries it (RGBM-encoded and decoded), cropped to the
    target's window in atlas mode."""
    from pdic.pdic_addon import gltf_export

    out = {}
    for obj, image in gltf_export.baked_objects(job.scene):
        rgb = gltf_export._image_rgb(image)
        decoded = gltf_export.decode_rgbm(gltf_export.encode_rgbm(rgb, gltf_export.rgbm_range(rgb)),
                                          gltf_export.rgbm_range(rgb))
        if job.atlas_layout is not None:
            x0, y0, w, h = job.atlas_layout.placement(obj.name).window
            decoded = decoded[y0:y0 + h, x0:x0 + w]
        out[obj.name] = decoded
    return out


def reference_render(bpy, job, width: int) -> np.ndarray:
    """PDIC's camera render (core/camera_render.py) of the quantised light maps, tone-mapped: (H, W, 3) 0..1."""
    import pdic
    import pdic_bake
    from pdic.core import camera_render as preview

    camera, aspect = pdic_bake.preview_camera(bpy, pdic, job.extraction.scene)
    height = int(round(width * aspect))
    radiance = preview.render_preview(job.extraction.scene, quantised_lightmaps(job), camera, width, height)
    return preview.tone_map(radiance).astype(np.float64) / 255.0


def lit_difference(shot: np.ndarray, reference: np.ndarray) -> tuple[float, int]:
    """Mean relative difference (linear) over lit pixels away from silhouettes and shadow edges."""
    a, b = srgb_to_linear(shot), srgb_to_linear(reference)
    lum = b.mean(axis=2)
    pad = np.pad(lum, 1, mode="edge")
    neighbours = np.stack([pad[1 + dy:pad.shape[0] - 1 + dy, 1 + dx:pad.shape[1] - 1 + dx]
                           for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
    smooth = neighbours.max(axis=0) <= 1.25 * neighbours.min(axis=0) + 1e-3
    lit = (lum > 0.02) & smooth
    rel = np.abs(a - b).mean(axis=2)[lit] / np.maximum(lum[lit], 0.02)
    return float(rel.mean()), int(lit.sum())


def bake_and_export(bpy, tmp_path: Path, blend: str, atlas_size: int):
    from pdic.core.settings import preset
    from pdic.pdic_addon import gltf_export
    from pdic.pdic_addon.job import BakeJob

    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "sample_blends" / f"{blend}.blend"))
    settings = preset("PREVIEW", photons=60_000, default_resolution=64, threads=2)
    job = BakeJob(bpy.context, settings, output_folder=str(tmp_path / "maps"), atlas_size=atlas_size)
    job.run()
    glb = gltf_export.export_glb(bpy.context, tmp_path / f"{blend}.glb")
    return job, glb


@pytest.mark.parametrize("blend, atlas_size", [("cornell_point", 512), ("textured_room", 0)])
def test_browser_view_matches_pdic_camera_render(blend, atlas_size, tmp_path, registered):
    require_web_setup()
    import bpy

    job, glb = bake_and_export(bpy, tmp_path, blend, atlas_size)
    reference = reference_render(bpy, job, WIDTH)
    height = reference.shape[0]
    state = screenshot(glb, tmp_path / "shot.png", WIDTH, height)
    assert state["bound"] == len(job.extraction.target_objects)
    shot = read_png(bpy, tmp_path / "shot.png")
    assert shot.shape == reference.shape
    difference, pixels = lit_difference(shot, reference)
    assert pixels > 0.2 * WIDTH * height, f"only {pixels} lit pixels compared"
    assert difference <= MAX_MEAN_RELATIVE_DIFFERENCE, f"{blend}: browser vs PDIC render {difference:.2%}"
    bpy.ops.wm.read_factory_settings(use_empty=True)
