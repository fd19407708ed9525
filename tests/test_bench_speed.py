"""bench/speed.py: a real bake in a process of its own, its measures and the table they make."""
from __future__ import annotations

import json

import pytest

from pdic.bench import speed


def test_a_bake_in_its_own_process_reports_what_it_measured(tmp_path, capsys):
    out = tmp_path / "speed.json"
    speed.main(["--scenes", "cornell256", "--qualities", "preview", "--runs", "1", "--out", str(out),
                "--work", str(tmp_path / "work")])
    (row,) = json.loads(out.read_text())["rows"]
    assert (row["scene"], row["quality"], row["checkout"]) == ("cornell256", "PREVIEW", "this")
    assert row["wall"] > 0 and row["cpu"] > 0 and 0 <= row["kernel"] <= row["cpu"]
    assert 0.05 < row["peak_gb"] < 8  # Blender, the box and its bake: hundreds of MB
    assert row["texels"] > 30_000 and row["records"] > 100 and row["rays"] > row["texels"]
    assert {"photons", "cache", "interpolate"} <= set(row["stages"])
    assert 0 < row["embree_share"]["cache"] <= 1
    assert row["peak_reset"] and row["kernels"]  # which compiled kernels ran (or why numpy did)
    assert "| cornell256 | PREVIEW |" in capsys.readouterr().out


def test_the_table_puts_each_checkout_in_its_own_columns():
    rows = [dict(scene="s", quality="FINAL", checkout=label, wall=wall, cpu=2 * wall, kernel=1.0, peak_gb=1.5)
            for label, wall in (("this", 10.0), ("baseline", 12.0), ("this", 11.0), ("baseline", 13.0))]
    table = speed.markdown(rows, ["this", "baseline"])
    assert table.splitlines()[-1] == ("| s | FINAL | 10.0 / 11.0 | 20 (1.0) / 22 (1.0) | 1.50 / 1.50 "
                                      "| 12.0 / 13.0 | 24 (1.0) / 26 (1.0) | 1.50 / 1.50 |")


@pytest.mark.parametrize("argv, message", [(["--scenes", "sponza3"], "unknown ['sponza3']"),
                                           (["--qualities", "final,fast"], "--qualities: 'final,fast'"),
                                           (["--baseline", "/nonexistent/pdic"], "not a PDIC checkout")])
def test_bad_arguments_say_which(argv, message):
    with pytest.raises(SystemExit, match=message.replace("[", r"\[").replace("]", r"\]")):
        speed.main(argv)
