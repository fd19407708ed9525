"""bench/path_referee.py, the third opinion between PDIC and Cycles, against an exact balance."""
from __future__ import annotations

import numpy as np
import pytest

from pdic.bench import path_referee
from pdic.core.lights import PointLight
from pdic.core.rays import RayCaster
from scenes import box_faces, quad, quad_scene


def test_path_traced_indirect_light_of_a_closed_box_balances_the_lamp_power():
    """Inside a closed box every reflected watt lands on a wall again, so the indirect flux onto
    the walls is rho / (1 - rho) times the lamp's P: the walls' area-mean indirect E / pi is
    rho / (1 - rho) P / (pi A) whatever the lamp's place. A bounce lost, or a path that stopped
    early without its Russian roulette weight, breaks it by rho^k."""
    rho, power = 0.6, 30.0
    scene = quad_scene(box_faces(), {}, (PointLight("lamp", np.array([0.3, 0.6, 0.7]), np.full(3, power)),),
                       albedo=rho)
    rng = np.random.default_rng(3)
    faces = rng.integers(0, 12, 3000)  # two equal triangles per unit face: uniform over the area
    tri = scene.geometry.positions[faces]
    s, t = rng.random((2, len(faces)))
    fold = s + t > 1
    s[fold], t[fold] = 1 - s[fold], 1 - t[fold]
    p = tri[:, 0] + s[:, None] * (tri[:, 1] - tri[:, 0]) + t[:, None] * (tri[:, 2] - tri[:, 0])
    n = scene.geometry.face_normals()[faces]
    mean, _ = path_referee.mean_indirect(scene, RayCaster(scene.geometry.positions), p, n, 40, rng)
    expected = rho / (1 - rho) * power / (np.pi * 6.0)
    assert mean.mean() == pytest.approx(expected, rel=0.03)
    assert np.allclose(mean.mean(axis=0), mean.mean(), rtol=1e-6)  # grey in, grey out


def _plane(resolution: int = 8):
    """A 1 x 1 m floor, its own light-map target, under a lamp."""
    faces = [quad([0, 0, 0], [1, 0, 0], [0, 1, 0])]
    lamp = PointLight("lamp", np.array([0.5, 0.5, 1.0]), np.full(3, 10.0))
    return quad_scene(faces, {"floor": (0, resolution)}, (lamp,))


def test_cycles_footprint_of_blender_5_0_keeps_the_half_texel_on_the_centre_triangle():
    """Blender 5.0's bake jitters over the centred half-texel square and keeps the points on the triangle under
    the texel's centre: a texel on the quad's diagonal, whose half-square straddles both triangles, keeps the
    part on that triangle only, and an interior texel's points all stay in its half-square."""
    scene = _plane()
    texels = np.array([3 * 8 + 3, 3 * 8 + 5])  # (3, 3) on the diagonal, (3, 5) inside triangle 0
    texel, p, n = path_referee.cycles_footprint(scene, 0, texels, 4, np.random.default_rng(1), blender_52=False)
    counts = np.bincount(texel, minlength=texels.max() + 1)[texels]
    assert 2 <= counts[0] <= 14 and counts[1] == 16
    x, y = (p[:, :2] - scene.geometry.positions[:, 0, :2].min(axis=0)).T * 8  # texel units
    diagonal = texel == texels[0]
    below = x[diagonal] >= y[diagonal] - 1e-9  # UV triangle 0 holds s >= t
    assert below.all() or (~below).all()
    assert (np.abs(x[diagonal] - 3.5) <= 0.25 + 1e-9).all()
    inner = ~diagonal
    assert (np.abs(x[inner] - 5.5) <= 0.25 + 1e-9).all() and (np.abs(y[inner] - 3.5) <= 0.25 + 1e-9).all()
    assert np.allclose(n, [0, 0, 1])


def test_cycles_footprint_of_blender_5_2_spans_the_whole_texel_on_the_chart():
    """Blender 5.2's bake integrates the whole texel, on the chart only: the points spread over more than half
    a texel each way and none leaves the texel."""
    scene = _plane()
    texel, p, _ = path_referee.cycles_footprint(scene, 0, np.array([3 * 8 + 5]), 4, np.random.default_rng(1),
                                                blender_52=True)
    x, y = (p[:, :2] - scene.geometry.positions[:, 0, :2].min(axis=0)).T * 8
    assert len(texel) == 16 and x.max() - x.min() > 0.5 and y.max() - y.min() > 0.5
    assert (np.abs(x - 5.5) <= 0.5).all() and (np.abs(y - 3.5) <= 0.5).all()


def test_refereed_error_replaces_the_pair_at_the_audited_texels_only():
    """With no texel audited it is bench.run's noise-corrected error; a texel whose path-traced truth is
    PDIC's own value (no noise) then adds nothing, where the pair had put PDIC 1.0 off."""
    from types import SimpleNamespace

    from pdic.bench.run import noise_corrected_error

    rng = np.random.default_rng(4)
    a, b = (1.0 + 0.05 * rng.standard_normal((4, 4, 3)) for _ in range(2))
    mine = 0.5 * (a + b) + 0.1
    mine[1, 2] += 1.0
    covered = np.ones((4, 4), bool)
    pair = [dict(images={"t": a}, coverage={"t": covered}), dict(images={"t": b}, coverage={"t": covered})]
    pdic = SimpleNamespace(indirect={"t": mine}, centre_inside={"t": covered})
    nothing = dict(texel=[], target=[], pt=[], pt_se=[])
    assert path_referee.refereed_error(pdic, pair, nothing) == pytest.approx(noise_corrected_error(
        pdic.indirect, pdic.centre_inside, pair), rel=1e-12)
    audit = dict(texel=[(1, 2)], target=["t"], pt=[mine[1, 2].copy()], pt_se=[0.0])
    ref = 0.5 * (a + b)
    excess = (((mine - ref) ** 2) - (a - b) ** 2 / 4).mean(axis=2)
    excess[1, 2] = 0.0
    truth = ref.mean(axis=2)
    truth[1, 2] = mine[1, 2].mean()
    expected = np.sqrt(excess.mean()) / truth.mean()
    assert path_referee.refereed_error(pdic, pair, audit) == pytest.approx(expected, rel=1e-12)
    assert expected < 0.5 * noise_corrected_error(pdic.indirect, pdic.centre_inside, pair)


def test_block_audit_counts_the_blocks_off_from_the_trace_for_each_baker(capsys):
    """A block is off for a baker when its mean is more than 20 % from the traced one."""
    blocks = [("t", 1, 2, 0.50, 0.30, 0.40, 0.01),  # PDIC 1.25x, the pair 0.75x: both off
              ("t", 3, 4, 1.15, 0.70, 1.00, 0.02),  # the pair alone
              ("t", 5, 6, 0.90, 1.10, 1.00, 0.02)]  # neither
    path_referee.print_block_audit("scene", {"blocks": blocks, "judged": 40})
    out = capsys.readouterr().out
    assert "3 of 40" in out and out.strip().endswith("PDIC 1, the pair 2")
