"""The floor at a wall's foot as a game engine samples the light map: Cycles' texels or PDIC's.

    .venv/bin/python bench/wall_foot.py [--densities 8,16] [--direct-only] [--out bench/plots/wall_foot.png]

The occluded building (bench/scenes.py ``load_occluded``), its six objects baked by the add-on's
``BakeJob`` at Final with each Texel Density. The floor slab runs under the partition walls at
x = 6 and 12 m: the floor's texels the walls' faces cut hold, in Cycles' convention, their
footprint's mean with the part under the wall at 0, those under the wall 0. PDIC's light map fills
them from their whole neighbours (docs/DEVIATIONS.md, buried-texels). An orthographic camera looks straight
down on the floor in front of each wall's face and reads the map bilinearly, as a GPU does
(``core.camera_render``): radiance = albedo x E / pi. Cycles' convention is the same bake's
``as_cycles`` images dilated from the raster coverage (what the switch off writes). Prints the
floor's radiance in bands of distance from the wall's face, relative to the band 40-50 cm away,
and writes the first wall's views with every profile. ``--direct-only`` bakes the direct light
alone (Passes: Indirect off), where texel validity votes only near lit texels.
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
from pdic.core.dilate import dilated_rgba  # noqa: E402
from pdic.core.pipeline import bake  # noqa: E402
from pdic.core.settings import preset  # noqa: E402

import bpy  # noqa: E402

WALLS = {"room 1, partition at x = 6 m": (5.9, -1), "room 3, partition at x = 12 m": (12.1, +1)}
"""(World x of a partition wall's face, the side of x its floor lies on): bench/scenes.py's walls are
20 cm thick at x = 6 and 12 m; each view is the 0.9 m x 2 m of room 1's or room 3's floor before it."""
DEPTH, Y, Z = 0.9, (0.2, 2.2), 2.5
"""Top-down views: depth from the wall's face (m), the floor's y range (m), the camera's height (m)."""
BANDS = (0.0, 0.01, 0.02, 0.04, 0.08, 0.16, 0.4, 0.5)
"""Edges of the distance bands from the wall's face, metres; the last band is the reference."""


def view_x(wall: tuple) -> tuple[float, float]:
    """The x range of the floor in front of ``wall`` (face, side)."""
    face, side = wall
    return (face - DEPTH, face) if side < 0 else (face, face + DEPTH)


def top_down(scene, wall: tuple, pixels_per_metre: int) -> tuple[Camera, int, int]:
    """An orthographic camera looking down on the floor before ``wall`` (scene-local), (camera, width, height)."""
    (x0, x1), (y0, y1) = view_x(wall), Y
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, Z]) - scene.origin_world
    camera = Camera(centre, np.eye(3), (x1 - x0) / 2, (y1 - y0) / 2, orthographic=True)
    return camera, int((x1 - x0) * pixels_per_metre), int((y1 - y0) * pixels_per_metre)


def profile(image: np.ndarray, wall: tuple) -> dict | None:
    """Mean radiance per distance band from the wall's face, over the band 40-50 cm away (None where that
    band is dark: room 3's floor there gets no direct light)."""
    (x0, x1), face = view_x(wall), wall[0]
    width = image.shape[1]
    d = np.abs(face - (x0 + (np.arange(width) + 0.5) / width * (x1 - x0)))
    column = image.mean(axis=(0, 2))
    bands = {(a, b): float(column[(d >= a) & (d < b)].mean()) for a, b in zip(BANDS[:-1], BANDS[1:])}
    far = bands[(BANDS[-2], BANDS[-1])]
    return {k: v / far for k, v in bands.items()} if far > 0 else None


def bake_maps(density: float, indirect: bool = True):
    """(core scene, {convention: light maps}, the bake's counters) of the building at ``density``."""
    objects = scenes.load_occluded()
    bpy.context.view_layer.update()  # the new objects join the view layer the job bakes from
    settings = preset("FINAL", texel_density=density, indirect=indirect)
    with tempfile.TemporaryDirectory() as work:
        _, scene = scenes.prepare(objects, settings, Path(work), area_sized=False)
    result = bake(scene, settings)
    cycles = {t.name: dilated_rgba(result.as_cycles(t.name), result.coverage[t.name], settings.padding + 2)
              for t in scene.targets}
    return scene, {"Cycles' texels": cycles, "PDIC light map": result.lightmaps}, result.stats["counters"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--densities", default="8,16", help="Texel Densities, texels per metre")
    ap.add_argument("--pixels-per-metre", type=int, default=400)
    ap.add_argument("--direct-only", action="store_true", help="bake the direct light alone")
    ap.add_argument("--out", default=str(ROOT / "bench" / "plots" / "wall_foot.png"))
    args = ap.parse_args(argv)

    pdic_addon.register()
    rows, shown = {}, None
    for density in [float(d) for d in args.densities.split(",")]:
        scene, maps, counters = bake_maps(density, not args.direct_only)
        print(f"{density:g} texels/m: {counters['texels_buried']:,} buried texels of {counters['texels_covered']:,}")
        for name, wall in WALLS.items():
            camera, width, height = top_down(scene, wall, args.pixels_per_metre)
            views = {label: render_preview(scene, m, camera, width, height) for label, m in maps.items()}
            for label, image in views.items():
                bands = profile(image, wall)
                if bands is None:
                    print(f"  {name}, {label}: dark 40-50 cm from the wall, not profiled")
                    continue
                rows[(density, name, label)] = bands
                print(f"  {name}, {label}: " + ", ".join(f"{100 * a:g}-{100 * b:g} cm {v:.3f}"
                                                         for (a, b), v in bands.items()))
            shown = shown or (density, name, wall, views)
    plot(shown, rows, Path(args.out), "Final, direct light only" if args.direct_only else "Final")
    print("wrote", args.out)
    return 0


def plot(shown, rows: dict, out: Path, mode: str = "Final"):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    density, name, wall, views = shown
    exposure = -np.log2(max(float(np.percentile(next(iter(views.values())), 99)), 1e-6))
    fig, axes = plt.subplots(1, 3, figsize=(11, 4.2), dpi=90, gridspec_kw=dict(width_ratios=(1, 1, 1.8)))
    for ax, (label, image) in zip(axes, views.items()):
        ax.imshow(tone_map(image, exposure), extent=(*view_x(wall), *Y), interpolation="nearest")
        ax.set_title(f"{label}, {density:g} texels/m", fontsize=9)
        ax.set_xlabel(f"x (m); the wall's face at x = {wall[0]}", fontsize=8)
    ax = axes[2]
    for (d, w, label), bands in rows.items():
        centres = [100 * (a + b) / 2 for a, b in bands]
        ax.semilogx(centres, list(bands.values()), "o-" if label.startswith("PDIC") else "s--", ms=4,
                    label=f"{label}, {d:g}/m, {w.split(',')[0]}")
    ax.set_xlabel("distance from the wall's face (cm)")
    ax.set_ylabel("floor radiance / its value 40-50 cm away")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6)
    fig.suptitle(f"Floor at a wall's foot, light map read bilinearly (occluded building, {mode}): {name}", fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
