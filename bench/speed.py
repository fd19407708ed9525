"""The README's speed table: PDIC's core bake of the bench scenes, each bake in a process of its own.

    .venv/bin/python -m bench.speed                                    # every scene, Final and Preview, twice
    .venv/bin/python -m bench.speed --scenes sponza16 --qualities FINAL --runs 3
    git worktree add ../old <commit>; cp core/native/pdic_native-*.so ../old/core/native/
    .venv/bin/python -m bench.speed --scenes sponza16 --qualities FINAL --runs 3 --baseline ../old

The scenes are the competitors bench's (`bench/competitors.py`: one object each, ``PDIC_Lightmap`` UVs
unwrapped by the add-on, the unwrap cached in ``bench/results/speed/``), baked at the preset's defaults with
the machine's default worker threads. Only the core bake is timed (`core.pipeline.bake`): not Blender's
start-up, the scene's import or the unwrap. Per bake: wall seconds, CPU seconds of all threads, of which
in the kernel, each stage's seconds and Embree's share of its thread time (the manifest's
``embree_share_<stage>``), and the process's peak resident memory during the bake (Blender and the loaded scene
included; on Linux the peak is reset once the scene is loaded, so the import's and the unwrap's do not count).

A fresh process per bake, because a bake's numbers depend on what the process did before (freed memory
kept by the allocator, pages already faulted in). With ``--baseline`` every bake is run once with that
checkout's code and once with this one's, alternating, the same scene from the same unwrap: the fair way to
time a change on a machine whose speed drifts by 10 % from one hour to the next. The baseline checkout sits
beside this one, as it reads the scenes from ``../shared/scenes`` too, with this machine's compiled kernels
copied in (without them it runs numpy's; each row records which kernels ran, ``kernels``).
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WORK = ROOT / "bench" / "results" / "speed"
SCENES = ("cornell256", "occluded", "sponza16", "sponza2048")
OPTIONAL_SCENES = ("occluded64", "occluded16area")
"""Scenes baked only when named: the building lit by 64 lamps, and by 16 ceiling panels (bench/competitors.py)."""
QUALITIES = ("FINAL", "PREVIEW")


def bake_once(scene_key: str, quality: str, work: Path) -> dict:
    """Load ``scene_key`` (the competitors bench's), bake it at ``quality``'s defaults, return the measures.

    Runs in the process of the checkout whose ``pdic`` package is imported (this one's or a baseline's)."""
    from pdic import pdic_addon
    from pdic.bench.competitors import SCENES as SPECS, load_scene
    from pdic.core.pipeline import bake
    from pdic.core.settings import preset

    pdic_addon.register()
    _, scene = load_scene(SPECS[scene_key], work / scene_key)
    peak_reset = _reset_peak()
    before = resource.getrusage(resource.RUSAGE_SELF)
    wall, cpu = time.perf_counter(), time.process_time()
    result = bake(scene, preset(quality))
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    after = resource.getrusage(resource.RUSAGE_SELF)
    counters = result.stats.get("counters", {})
    return dict(scene=scene_key, quality=quality, wall=wall, cpu=cpu, kernel=after.ru_stime - before.ru_stime,
                peak_gb=peak_bytes() / 2 ** 30, texels=counters.get("texels_covered"),
                rays=counters.get("rays_cast"), records=counters.get("records_total"),
                stages={k: round(v, 2) for k, v in result.stats.get("seconds", {}).items()},
                embree_share={k[len("embree_share_"):]: round(v, 3) for k, v in counters.items()
                              if k.startswith("embree_share_")},
                kernels=result.stats.get("kernels"), peak_reset=peak_reset)


def _reset_peak() -> bool:
    """Start VmHWM afresh at the current resident size (Linux: ``clear_refs`` 5). False where that failed:
    the peak is then the process's, the scene's import and unwrap included (the row says so)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def peak_bytes() -> int:
    """This process's peak resident memory, bytes: VmHWM (ru_maxrss keeps the parent's peak across fork/exec on
    Linux, so a subprocess of a big bench would report the bench's peak)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return maxrss if sys.platform == "darwin" else maxrss * 1024  # bytes on macOS, KB elsewhere


def run_one(checkout: Path, scene_key: str, quality: str, work: Path) -> dict:
    """One bake in a fresh interpreter importing ``checkout``'s package."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--one", f"{scene_key},{quality}", "--root", str(checkout),
           "--work", str(work)]
    proc = subprocess.run(cmd, cwd=checkout, capture_output=True, text=True)
    lines = [x for x in proc.stdout.splitlines() if x.startswith("SPEED ")]
    if proc.returncode != 0 or not lines:
        raise SystemExit(f"bench.speed: the bake of {scene_key} at {quality} in {checkout} failed "
                         f"(exit {proc.returncode}):\n{(proc.stderr or proc.stdout or '(no output)')[-3000:]}")
    return json.loads(lines[-1][len("SPEED "):])


def markdown(rows: list, labels: list) -> str:
    """Rows grouped by scene and quality, one column per checkout (``labels``), every run listed."""
    out = ["| scene | quality | " + " | ".join(f"{label}: wall s | CPU s (kernel) | peak GB" for label in labels) + " |",
           "| --- | --- | " + " | ".join("--- | --- | ---" for _ in labels) + " |"]
    keys = list(dict.fromkeys((r["scene"], r["quality"]) for r in rows))
    for scene, quality in keys:
        cells = []
        for label in labels:
            runs = [r for r in rows if (r["scene"], r["quality"], r["checkout"]) == (scene, quality, label)]
            cells.append(" / ".join(f"{r['wall']:.1f}" for r in runs))
            cells.append(" / ".join(f"{r['cpu']:.0f} ({r['kernel']:.1f})" for r in runs))
            cells.append(" / ".join(f"{r['peak_gb']:.2f}" for r in runs))
        out.append(f"| {scene} | {quality} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default=",".join(SCENES),
                    help=f"comma-separated: {', '.join(SCENES + OPTIONAL_SCENES)}")
    ap.add_argument("--qualities", default=",".join(QUALITIES))
    ap.add_argument("--runs", type=int, default=2, help="bakes of each scene and quality (per checkout)")
    ap.add_argument("--baseline", type=Path, help="another checkout to alternate with (its code, this bench)")
    ap.add_argument("--out", type=Path, default=WORK / "speed.json")
    ap.add_argument("--one", help=argparse.SUPPRESS)  # scene,quality: bake once in this process
    ap.add_argument("--root", type=Path, default=ROOT, help=argparse.SUPPRESS)
    ap.add_argument("--work", type=Path, default=WORK, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        sys.path.insert(0, str(args.root))
        import pdic_bootstrap

        pdic_bootstrap.load()
        scene_key, quality = args.one.split(",")
        print("SPEED " + json.dumps(bake_once(scene_key, quality, args.work)), flush=True)
        return
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    unknown = [s for s in scenes if s not in SCENES + OPTIONAL_SCENES]
    if unknown:
        raise SystemExit(f"--scenes: unknown {unknown}; known: {', '.join(SCENES + OPTIONAL_SCENES)}")
    qualities = [q.strip().upper() for q in args.qualities.split(",") if q.strip()]
    if not qualities or set(qualities) - set(QUALITIES):
        raise SystemExit(f"--qualities: {args.qualities!r}; known: {', '.join(QUALITIES)}")
    if args.baseline is not None and not (args.baseline / "pdic_bootstrap.py").is_file():
        raise SystemExit(f"--baseline {args.baseline}: not a PDIC checkout (no pdic_bootstrap.py there)")
    checkouts = [("this", ROOT)] + ([("baseline", args.baseline.resolve())] if args.baseline else [])
    rows = []
    args.out.parent.mkdir(parents=True, exist_ok=True)
    for scene in scenes:
        for quality in qualities:
            for run in range(args.runs):
                # Alternate which checkout goes first, so neither always bakes on the warmer machine.
                for label, checkout in (checkouts if run % 2 == 0 else checkouts[::-1]):
                    row = dict(run_one(checkout, scene, quality, args.work), checkout=label)
                    rows.append(row)
                    # Written after every bake: a later bake that fails keeps the ones measured.
                    args.out.write_text(json.dumps(dict(rows=rows, argv=sys.argv[1:]), indent=1))
                    print(f"{label:8s} {scene:10s} {quality:7s} wall {row['wall']:6.1f} s  CPU {row['cpu']:6.1f} s "
                          f"(kernel {row['kernel']:5.1f})  peak {row['peak_gb']:.2f} GB  {row['stages']}  "
                          f"Embree {row['embree_share']}", flush=True)
    print()
    print(markdown(rows, [label for label, _ in checkouts]))


if __name__ == "__main__":
    main()
