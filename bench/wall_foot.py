"""The floor at a wall's foot as a game engine samples the light map: buried texels black or filled.

    .venv/bin/python bench/wall_foot.py [--density 8] [--out bench/plots/wall_foot.png]

The occluded building (bench/scenes.py ``load_occluded``), its six objects baked by the add-on's
``BakeJob`` at Final with a Texel Density of ``--density`` texels/m. The floor slab runs under the
partition wall at x = 6 m, so the floor's texels there are buried (docs/DEVIATIONS.md,
buried-texels). An orthographic camera looks straight down on room 1's floor in front of the
wall's face (x = 5.9 m) and reads the light map bilinearly, as a GPU does
(``core.camera_render``): radiance = albedo x E / pi. The same bake's map with buried texels left
black (Cycles' convention) is the direct + indirect images dilated from the raster coverage, what
the switch off gives. Prints the floor's radiance in bands of distance from the wall's face,
relative to the band 40-50 cm away, for both maps, and writes the two views with the profile.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import pdic_bootstrap  # noqa: E402

pdic_bootstrap.load()
from bench import scenes  # noqa: E402
from pdic import pdic_addon  # noqa: E402
from pdic.core.camera_render import Camera, render_preview, tone_map  # noqa: E402
from pdic.core.dilate import dilate  # noqa: E402
from pdic.core.pipeline import bake  # noqa: E402
from pdic.core.settings import preset  # noqa: E402

import bpy  # noqa: E402

FACE_X = 5.9
"""World x of the partition wall's face toward room 1 (bench/scenes.py: wall at x = 6 m, 20 cm thick)."""
VIEW = dict(x=(4.9, FACE_X), y=(0.2, 2.2), z=2.5)
"""World frame of the top-down view: a 1 m x 2 m patch of room 1's floor ending at the wall's face."""
BANDS = (0.0, 0.01, 0.02, 0.04, 0.08, 0.16, 0.4, 0.5)
"""Edges of the distance bands from the wall's face, metres; the last band is the reference."""


def top_down(scene, pixels_per_metre: int) -> tuple[Camera, int, int]:
    """An orthographic camera over VIEW in scene-local coordinates, (camera, width, height)."""
    (x0, x1), (y0, y1) = VIEW["x"], VIEW["y"]
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, VIEW["z"]]) - scene.origin_world
    camera = Camera(centre, np.eye(3), (x1 - x0) / 2, (y1 - y0) / 2, orthographic=True)
    return camera, int((x1 - x0) * pixels_per_metre), int((y1 - y0) * pixels_per_metre)


def profile(image: np.ndarray) -> dict:
    """Mean radiance (over rows and channels) per distance band from the wall's face."""
    width = image.shape[1]
    x = VIEW["x"][0] + (np.arange(width) + 0.5) / width * (VIEW["x"][1] - VIEW["x"][0])
    d = FACE_X - x
    column = image.mean(axis=(0, 2))
    return {(a, b): float(column[(d >= a) & (d < b)].mean()) for a, b in zip(BANDS[:-1], BANDS[1:])}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--density", type=float, default=8.0, help="Texel Density, texels per metre")
    ap.add_argument("--pixels-per-metre", type=int, default=400)
    ap.add_argument("--out", default=str(ROOT / "bench" / "plots" / "wall_foot.png"))
    args = ap.parse_args(argv)

    pdic_addon.register()
    objects = scenes.load_occluded()
    bpy.context.view_layer.update()  # the new objects join the view layer the job bakes from
    settings = preset("FINAL", texel_density=args.density)
    with tempfile.TemporaryDirectory() as work:
        _, scene = scenes.prepare(objects, settings, Path(work), area_sized=False)
    result = bake(scene, settings)
    black = {}
    for target in scene.targets:
        n = target.name
        rgb, covered = dilate(result.direct[n] + result.indirect[n], result.coverage[n], settings.padding + 2)
        black[n] = np.concatenate([rgb, covered[..., None].astype(np.float32)], axis=2)
    camera, width, height = top_down(scene, args.pixels_per_metre)
    views = {"buried texels black (Cycles)": render_preview(scene, black, camera, width, height),
             "buried texels filled (PDIC)": render_preview(scene, result.lightmaps, camera, width, height)}
    buried = int(result.stats["counters"].get("texels_buried", 0))
    print(f"{args.density:g} texels/m: {buried:,} buried texels of {int(sum(c.sum() for c in result.coverage.values())):,}")
    rows = {}
    for label, image in views.items():
        bands = profile(image)
        far = bands[(BANDS[-2], BANDS[-1])]
        rows[label] = {k: v / far for k, v in bands.items()}
        print(label + ": " + ", ".join(f"{100 * a:g}-{100 * b:g} cm {v:.3f}" for (a, b), v in rows[label].items()))
    plot(views, rows, args.density, Path(args.out))
    print("wrote", args.out)
    return 0


def plot(views: dict, rows: dict, density: float, out: Path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    exposure = -np.log2(max(float(np.percentile(next(iter(views.values())), 99)), 1e-6))
    fig, axes = plt.subplots(1, 3, figsize=(11, 4.2), dpi=90, gridspec_kw=dict(width_ratios=(1, 1, 1.6)))
    for ax, (label, image) in zip(axes, views.items()):
        ax.imshow(tone_map(image, exposure), extent=(*VIEW["x"], *VIEW["y"]), interpolation="nearest")
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("x (m); the wall's face at the right edge", fontsize=8)
    ax = axes[2]
    for label, bands in rows.items():
        centres = [100 * (a + b) / 2 for a, b in bands]
        ax.semilogx(centres, list(bands.values()), "o-", label=label)
    ax.set_xlabel("distance from the wall's face (cm)")
    ax.set_ylabel("floor radiance / its value 40-50 cm away")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.suptitle(f"Floor at a wall's foot, light map read bilinearly (occluded building, {density:g} texels/m, Final)",
                 fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
