"""A storeroom of many small stacked props: PDIC Final against Cycles, texel by texel.

    .venv/bin/python bench/storeroom.py [--density 16] [--spp 512] [--bounces 32] [--seed 0] [--out DIR]
        [--quality PREVIEW] [--deviations crevice_records=0] [--set r_min_texels=3] [--competitors 4,16,64]

A game level's interior is one room and many small props, each its own object with a small light map,
stacked on each other and on shelves. A closed room (8 x 6 x 3 m, 20 cm walls, one object), three
shelving units (uprights and 2 cm boards, one object each) and CRATES crates of 20-60 cm, each its own
object and albedo (0.2-0.8, some coloured), in piles of one to four whose faces touch exactly, some
turned about z, some on the shelves' boards; a 200 W point light under the ceiling and a 600 W spot
aimed down at a corner pile. Nothing else in the bench has a hundred light maps of a few hundred texels
each, faces lying on faces, or props whose only light comes from beside them. PDIC bakes every object
at ``--density`` texels per metre through the add-on's ``BakeJob``; Cycles bakes Diffuse Direct and
Diffuse Indirect into the same ``PDIC_Lightmap`` UVs with seeds 1 and 2 (bench/town.py ``reference``,
cached in ``--out``), the pair's noise subtracted. Prints, per object kind and over all, the error per
texel and on 8x8 blocks, the mean ratio and the texels one baker lights and the other leaves black.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / "tests"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))
import pdic_bootstrap  # noqa: E402

pdic_bootstrap.load()
import bpy  # noqa: E402

from bench.scenes import boxes_mesh  # noqa: E402
from bench.town import run_scene  # noqa: E402
from test_cathedral_direct_vs_cycles import _diffuse_material  # noqa: E402
from test_direct_vs_cycles import _world  # noqa: E402

ROOM = (8.0, 6.0, 3.0)
"""Inside size of the room, metres; the floor at z = 0, centred on the origin in x and y."""
WALL = 0.2
CRATES = 72
"""Crates in all (piles on the floor and crates on the shelves)."""
POINT_WATTS = 200.0
SPOT_WATTS = 600.0
COLOURS = ((0.8, 0.8, 0.8), (0.2, 0.2, 0.2), (0.5, 0.5, 0.5), (0.75, 0.3, 0.2), (0.2, 0.5, 0.3), (0.6, 0.55, 0.3))


def room_boxes() -> list:
    """The room's floor, ceiling and four walls as boxes, their inner faces facing into the room."""
    x, y, z = ROOM[0] / 2, ROOM[1] / 2, ROOM[2]
    w = WALL
    return [((-x - w, -y - w, -w), (x + w, y + w, 0.0)), ((-x - w, -y - w, z), (x + w, y + w, z + w)),
            ((-x - w, -y - w, 0.0), (-x, y + w, z)), ((x, -y - w, 0.0), (x + w, y + w, z)),
            ((-x, -y - w, 0.0), (x, -y, z)), ((-x, y, 0.0), (x, y + w, z))]


def shelf_boxes(x0: float, y0: float) -> tuple[list, list]:
    """(boxes, board tops): a 1.6 x 0.4 m shelving unit, 2 m tall, its back 1 cm off the wall at y0."""
    boxes = [((x0 + dx, y0 + dy, 0.0), (x0 + dx + 0.04, y0 + dy + 0.04, 2.0))
             for dx in (0.0, 1.56) for dy in (0.0, 0.36)]
    tops = []
    for z in (0.1, 0.8, 1.5):
        boxes.append(((x0 + 0.04, y0, z - 0.02), (x0 + 1.56, y0 + 0.4, z)))
        tops.append((x0 + 0.04, y0, z, x0 + 1.56, y0 + 0.4))
    return boxes, tops


def layout(seed: int = 11) -> tuple[list, list]:
    """([(name, boxes, albedo)] of the shelves, [(name, (lo, hi), albedo, turn)] of the crates): seeded."""
    rng = np.random.default_rng(seed)
    shelves, crates = [], []
    spots = []  # (x0, y0, z, x1, y1): surfaces crates stand on
    for i, x0 in enumerate((-3.6, -1.6, 0.4)):
        boxes, tops = shelf_boxes(x0, ROOM[1] / 2 - 0.41)
        shelves.append((f"Shelf_{i}", boxes, COLOURS[2]))
        spots += tops
    on_shelves = 0
    while len(crates) < CRATES:
        k = len(crates)
        colour = COLOURS[int(rng.integers(len(COLOURS)))]
        if on_shelves < CRATES // 4:  # a crate on a board, resting on it
            x0, y0, z, x1, y1 = spots[on_shelves % len(spots)]
            s = float(rng.uniform(0.15, 0.35))
            cx = float(rng.uniform(x0 + s / 2, x1 - s / 2))
            crates.append((f"Crate_{k:03d}", ((cx - s / 2, y0 + 0.02, z), (cx + s / 2, y0 + 0.02 + s, z + s * 0.8)),
                           colour, 0.0))
            on_shelves += 1
            continue
        # a pile on the floor: one to four crates, each smaller than the one under it, faces touching
        cx, cy = float(rng.uniform(-3.4, 3.4)), float(rng.uniform(-2.6, 1.8))
        turn = float(rng.choice([0.0, 0.0, rng.uniform(0, math.pi / 2)]))
        z, s = 0.0, float(rng.uniform(0.4, 0.6))
        for _ in range(int(rng.integers(1, 5))):
            if len(crates) >= CRATES:
                break
            h = s * float(rng.uniform(0.6, 1.0))
            crates.append((f"Crate_{len(crates):03d}", ((cx - s / 2, cy - s / 2, z), (cx + s / 2, cy + s / 2, z + h)),
                           colour, turn))
            z, s = z + h, s * float(rng.uniform(0.6, 0.9))
    return shelves, crates


def build() -> list:
    """A factory-fresh file with the storeroom and its two lights; returns the mesh objects."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    _world(bpy)
    objects = []

    def add(name, boxes, albedo, turn=0.0, pivot=None):
        if pivot is not None:  # turned about z round the pile's axis: the mesh about its origin, moved there
            boxes = [((lo[0] - pivot[0], lo[1] - pivot[1], lo[2]), (hi[0] - pivot[0], hi[1] - pivot[1], hi[2]))
                     for lo, hi in boxes]
        mesh = boxes_mesh(name, boxes)
        mesh.materials.append(_diffuse_material(bpy, name + "Mat", albedo))
        ob = bpy.data.objects.new(name, mesh)
        if pivot is not None:
            ob.location = (pivot[0], pivot[1], 0.0)
            ob.rotation_euler = (0.0, 0.0, turn)
        objects.append(ob)

    add("Room", room_boxes(), (0.7, 0.7, 0.68))
    shelves, crates = layout()
    for name, boxes, albedo in shelves:
        add(name, boxes, albedo)
    for name, (lo, hi), albedo, turn in crates:
        pivot = None if turn == 0.0 else ((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2)
        add(name, [(lo, hi)], albedo, turn, pivot)
    for ob in objects:
        bpy.context.scene.collection.objects.link(ob)
    point = bpy.data.lights.new("Lamp", "POINT")
    point.energy, point.shadow_soft_size = POINT_WATTS, 0.0
    lamp = bpy.data.objects.new("Lamp", point)
    lamp.location = (0.5, -0.5, ROOM[2] - 0.3)
    spot = bpy.data.lights.new("Spot", "SPOT")
    spot.energy, spot.shadow_soft_size, spot.spot_size, spot.spot_blend = SPOT_WATTS, 0.0, math.radians(60), 0.2
    spot_ob = bpy.data.objects.new("Spot", spot)
    spot_ob.location = (-2.5, -1.5, ROOM[2] - 0.2)
    spot_ob.rotation_euler = (math.radians(20), math.radians(-20), 0.0)
    for ob in (lamp, spot_ob):
        bpy.context.scene.collection.objects.link(ob)
    bpy.context.view_layer.update()
    return objects


def kind(name: str) -> str:
    return name.split("_")[0].lower()


def main(argv=None):
    run_scene("storeroom", build, kind, argv, density=16.0, spp=512)

if __name__ == "__main__":
    main()
