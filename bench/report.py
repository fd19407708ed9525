"""Markdown tables and PNG plots from ``results.json`` (bench only: uses matplotlib, see requirements-bench.txt)."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def _f(x, digits=3):
    if x is None:
        return "-"
    if isinstance(x, (int, np.integer)):
        return f"{x:,}"
    if abs(x) >= 100:
        return f"{x:,.0f}"
    return f"{x:.{digits}g}"


def _table(header: list, rows: list) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def markdown(results: dict) -> str:
    m = results.get("machine", {})
    out = [f"# PDIC benchmark results{' (quick run)' if results.get('quick') else ''}\n",
           f"Measured {m.get('date', '')} on {m.get('cpu', '?')}, {m.get('cores', '?')} cores "
           f"(shared with other jobs), {m.get('system', '')}, Blender {m.get('blender', '')} (bpy wheel), "
           f"Python {m.get('python', '')}. Command: `.venv/bin/python -m bench.run"
           f"{' --quick' if results.get('quick') else ''}`.\n"]
    e = results.get("errors")
    if e:
        out.append(f"\n## Run time against error (Cornell point light, {e['resolution']}x{e['resolution']} per object, "
                   f"{e['bounces']} diffuse bounces)\n\n"
                   f"Error = relative RMSE over the texels Cycles bakes, against Cycles at {e['reference_spp']} spp "
                   f"(indirect; its own noise ~{_f(100 * e.get('reference_noise_indirect', float('nan')), 2)} % "
                   f"by the ladder's 1/sqrt(spp) fit) + 256 spp direct. PDIC times are the core bake "
                   f"(no extraction); Cycles times are the `bpy.ops.object.bake` calls.\n\n")
        rows = [[r["method"], f"{r['photons']:,} photons", _f(r["seconds"]), _f(100 * r["error_all"]),
                 _f(100 * r["error_indirect"])] for r in e["pdic"]]
        rows += [[r["method"], f"{r['spp']} spp", f"{_f(r['seconds'])} / {_f(r['seconds_indirect'])}",
                  _f(100 * r["error_all"]), _f(100 * r["error_indirect"])] for r in e["cycles"]]
        out.append(_table(["method", "setting", "seconds (all / indirect-only bake)", "error all %",
                           "error indirect %"], rows))
        for kind in ("all", "indirect"):
            sp = e.get(f"speedup_{kind}")
            if sp:
                fit = e[f"cycles_fit_{kind}"]
                out.append(f"\nEqual-error speed-up, {kind} (Cycles fitted as error = {_f(fit['A'])} t^{_f(fit['b'])}):\n\n")
                out.append(_table(["PDIC", "photons", "error %", "PDIC s", "Cycles s at equal error", "speed-up"],
                                  [[r["method"], f"{r['photons']:,}", _f(100 * r["error"]), _f(r["pdic_seconds"]),
                                    _f(r["cycles_seconds_at_equal_error"]), f"{_f(r['speedup'])}x"] for r in sp]))
        if e.get("pdic_512") and e.get("cycles_512"):
            c = e["cycles_512"]
            sp = e["speedup_512"]
            res = c["resolution"]
            out.append(f"\n### At {res}x{res} per object (8 objects), both measured per texel\n\n"
                       f"Cycles' error at {res}^2 is its noise (its estimator is unbiased): two {c['spp']}-spp "
                       f"indirect bakes with different seeds give rms(b1 - b2) / sqrt 2 = "
                       f"{_f(100 * c['error_indirect'])} % in {_f(c['seconds'])} s per bake. Noise falls as "
                       f"1/sqrt(spp) and time grows with spp, so equal error costs "
                       f"{_f(c['seconds'])} s x (noise / error)^2. PDIC's per-texel error is measured against the "
                       f"mean of the two bakes with their known noise subtracted (E|PDIC - ref|^2 = error^2 + "
                       f"noise^2 / 2); 'downsampled' is its {res // e['resolution']}x{res // e['resolution']} "
                       f"block average against the {e['resolution']}^2 reference.\n\n")
            out.append(_table(["PDIC", "photons", "seconds", "error indirect %", "downsampled %",
                               "Cycles spp at equal error", "Cycles s at equal error", "speed-up"],
                              [[r["method"], f"{r['photons']:,}", _f(r["pdic_seconds"]), _f(100 * r["error"]),
                                _f(100 * r["error_downsampled"]), _f(r["cycles_spp_at_equal_error"]),
                                _f(r["cycles_seconds_at_equal_error"]), f"{_f(r['speedup'])}x"] for r in sp["rows"]]))
            out.append(f"\nAt the issue's target of {_f(100 * sp['target_error'])} % indirect error Cycles needs "
                       f"~{_f(sp['cycles_spp_at_target'])} spp = ~{_f(sp['cycles_seconds_at_target'])} s at "
                       f"{res}^2.\n")
    t = results.get("tables")
    if t:
        out.append("\n## Table 1: passes (Final quality, photon-path reuse on)\n\n")
        rows = []
        for r in t["table1"]:
            s = r["stage_seconds"]
            rows.append([r["scene"], f"{r['triangles']:,}", f"{r['texels']:,}", f"{r['photons_emitted']:,}",
                         f"{r['photons_stored']:,}", r["bounces"], f"{r['records']:,}", f"{r['hole_records']:,}",
                         _f(s.get("photons", 0)), _f(s.get("cache", 0)),
                         _f(s.get("photon_direct", 0) + s.get("refine", 0)),
                         _f(s.get("direct", 0)), _f(s.get("validity", 0) + s.get("interpolate", 0)),
                         _f(r["seconds"])])
        out.append(_table(["scene", "triangles", "texels", "photons emitted", "stored", "bounces", "records",
                           "hole records", "pass 1 s", "pass 2 s", "pass 3 s", "direct s", "texels s", "total s"],
                          rows))
        out.append("\n## Table 2: refinement rays, standard final gathering vs photon-path reuse\n\n")
        rows = [[p["scene"], f"{p['standard_rays']:,}", f"{p['reuse_rays']:,}", f"{100 * p['rays_saved']:.0f} %",
                 _f(p["standard_seconds"]), _f(p["reuse_seconds"]),
                 _f(None if p["standard_error_indirect"] is None else 100 * p["standard_error_indirect"]),
                 _f(None if p["reuse_error_indirect"] is None else 100 * p["reuse_error_indirect"])]
                for p in t["table2"]]
        out.append(_table(["scene", "standard rays", "reuse rays", "saved", "standard s", "reuse s",
                           "standard error ind. %", "reuse error ind. %"], rows))
        out.append("\nRays = gathering rays (real cell rays + probe + zone-visibility rays), without the shadow rays "
                   "at gather hits. Seconds = pass 3: refinement plus, with reuse, the photons' direct light that "
                   "virtual rays read.\n")
        out.append("\n## Figure 5: [Chr99] vs the pass-2 preview (same photon map and texels)\n\n")
        rows = []
        for f in t["figure5"]:
            err_c = f.get("christensen_error_indirect")
            err_p = f.get("preview_error_indirect")
            rows.append([f["scene"], f"{f['photons']:,}", _f(f["photon_seconds"]), _f(f["christensen_seconds"]),
                         _f(f["preview_seconds"]), _f(None if err_c is None else 100 * err_c),
                         _f(None if err_p is None else 100 * err_p),
                         _f(100 * f["christensen_vs_preview_rmse"]) if "christensen_vs_preview_rmse" in f else "-"])
        out.append(_table(["scene", "photons", "pass 1 s", "[Chr99] s", "preview (pass 2 + lookup) s",
                           "[Chr99] error ind. %", "preview error ind. %", "difference %"], rows))
        refs = t.get("references", {})
        out.append("\nReferences: Cornell against the committed 16384-spp Cycles bake. "
                   + " ".join(f"{n}: two {r['spp']}-spp Cycles INDIRECT bakes ({_f(r['seconds'])} s for both; "
                              f"{_f(100 * r['noise_indirect'])} % noise each), errors with that noise subtracted "
                              f"(E|x - ref|^2 = error^2 + noise^2 / 2)." for n, r in refs.items())
                   + " 'difference' is the relative RMS difference between [Chr99] and the preview.\n")
    s = results.get("scaling")
    if s:
        out.append("\n## Scaling (Cornell, one process per point, peak RSS)\n\n")
        rows = [[p["kind"], p["quality"], f"{p['value']:,}", f"{p['texel_samples']:,}", f"{p['photons_stored']:,}",
                 _f(p["seconds"]), _f(p["peak_rss_mb"])] for p in s["points"]]
        out.append(_table(["axis", "quality", "value", "texel samples", "photons stored", "seconds", "peak MB"], rows))
        out.append("\nCost model per pass, t = c0 + c1 x (x = emitted photons or texel samples), with the log-log "
                   "slope (1 = linear):\n\n")
        rows = []
        for k, v in s["cost_model"].items():
            if "c1_microseconds" in v:
                rows.append([k, v["per"], _f(v["c0_seconds"]), _f(v["c1_microseconds"]), _f(v["loglog_slope"])])
        out.append(_table(["quality:pass", "x", "c0 s", "c1 us per x", "log-log slope"], rows))
        rows = [[k, _f(v["c0_mb"]), _f(v["bytes_per_unit"])] for k, v in s["cost_model"].items() if "c0_mb" in v]
        if rows:
            out.append("\n" + _table(["memory", "c0 MB", "bytes per unit"], rows))
    r = results.get("rebake")
    if r:
        out.append("\n## Re-bakes with a BakeCache (Cornell Final)\n\n")
        out.append(_table(["bake", "seconds", "of first", "counters"], [
            ["first", _f(r["first_seconds"]), "100 %", ""],
            ["unchanged", _f(r["unchanged_seconds"]), f"{100 * r['unchanged_ratio']:.1f} %",
             ", ".join(f"{k} {v}" for k, v in r["unchanged_counters"].items())],
            [f"{r['changed_object']} at 2x resolution", _f(r["one_resolution_seconds"]),
             f"{100 * r['one_resolution_ratio']:.1f} %",
             ", ".join(f"{k} {v}" for k, v in r["one_resolution_counters"].items())]]))
    if results.get("competitors"):
        from . import competitors

        out.append(competitors.markdown(results["competitors"]))
    return "".join(out)


def plots(results: dict, out: Path, images: dict) -> list:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    e = results.get("errors")
    if e:
        fig, axes = plt.subplots(1, 2, figsize=(9, 3.6), dpi=90)
        for ax, kind, t_key in ((axes[0], "all", "seconds"), (axes[1], "indirect", "seconds_indirect")):
            for adaptive, style in ((False, "o-"), (True, "s--")):
                c = [r for r in e["cycles"] if r["adaptive"] == adaptive]
                if c:
                    ax.loglog([r[t_key] for r in c], [100 * r[f"error_{kind}"] for r in c], style,
                              label="Cycles" + (" adaptive" if adaptive else ""))
                    for r in c:
                        ax.annotate(f"{r['spp']}", (r[t_key], 100 * r[f"error_{kind}"]), fontsize=7)
            for quality, style in (("PREVIEW", "^"), ("FINAL", "D")):
                p = [r for r in e["pdic"] if r["quality"] == quality]
                if p:
                    ax.loglog([r["seconds"] for r in p], [100 * r[f"error_{kind}"] for r in p], style,
                              label=f"PDIC {quality.title()}")
            ax.set_xlabel("seconds")
            ax.set_ylabel("relative RMSE %")
            ax.set_title(f"Cornell {e['resolution']}^2: {'direct+indirect' if kind == 'all' else 'indirect only'}")
            ax.grid(True, which="both", alpha=0.3)
        axes[0].legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / "error_vs_time.png")
        plt.close(fig)
        written.append("error_vs_time.png")
    s = results.get("scaling")
    if s and s["points"]:
        fig, axes = plt.subplots(1, 2, figsize=(9, 3.6), dpi=90)
        for ax, kind in zip(axes, ("photons", "texels")):
            for quality in ("PREVIEW", "FINAL"):
                pts = [p for p in s["points"] if p["kind"] == kind and p["quality"] == quality]
                if not pts:
                    continue
                x = [p["value"] for p in pts]
                ax.loglog(x, [p["seconds"] for p in pts], "o-", label=f"{quality.title()} time (s)")
                ax.loglog(x, [p["peak_rss_mb"] for p in pts], "s--", label=f"{quality.title()} peak MB")
            ax.set_xlabel("emitted photons" if kind == "photons" else "light-map texels")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / "scaling.png")
        plt.close(fig)
        written.append("scaling.png")
    if "Cornell" in images:
        img = images["Cornell"]
        name = "Floor" if "Floor" in img["preview"] else sorted(img["preview"])[0]
        fig, axes = plt.subplots(1, 2, figsize=(6, 3.2), dpi=90)
        vmax = float(np.percentile(img["preview"][name], 99))
        for ax, label in zip(axes, ("christensen", "preview")):
            ax.imshow(np.clip(img[label][name] / max(vmax, 1e-30), 0, 1), origin="lower")
            ax.set_title({"christensen": "[Chr99]", "preview": "PDIC pass 2"}[label] + f": {name}", fontsize=9)
            ax.axis("off")
        fig.tight_layout()
        fig.savefig(out / "figure5.png")
        plt.close(fig)
        written.append("figure5.png")
    if results.get("competitors"):
        from . import competitors

        written += competitors.plots(results["competitors"], out, plt)
    return written


def write(results: dict, out: Path, images: dict | None = None) -> None:
    text = markdown(results)
    try:
        names = plots(results, out, images or {})
    except ImportError:  # matplotlib missing: tables only
        names = []
        text += "\n(plots skipped: `pip install -r requirements-bench.txt`)\n"
    if names:
        text += "\n## Plots\n\n" + "".join(f"![{n}](plots/{n})\n" for n in names)
    (out / "results.md").write_text(text)
