"""``report.html``: one self-contained page (pictures embedded as PNG data URIs) for a GNC engineer.

Sections: the run; the tables beside the reference report's; error CDFs per look; confidence
calibration (reported 1-sigma against actual error, status against correctness); extraction
quality against the true horizon; the worst cases with their score map (truth and fix marked) and
the skyline overlay (extracted, true, matched); the rejected poses.  Metres and degrees.
"""
from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path

import numpy as np

from render_service.campaign.scoring import WRONG_HEADING_DEG, WRONG_M

#: Worst cases shown with their pictures.
N_WORST = 6
COLORS = {"binary": "#444444", "clean": "#1f77b4", "realistic": "#2ca02c", "distorted": "#d62728"}
STATUS_COLORS = {"ok": "#2ca02c", "ambiguous": "#ff7f0e", "failed": "#d62728"}


def _plt():
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    return plt


def _png(fig) -> str:
    plt = _plt()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def _file_png(path: Path) -> str | None:
    if not path.is_file():
        return None
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode()


def _f(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def _cdf_figure(rows: list[dict]):
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    for ax, col, label, limit in ((axes[0], "error_m", "position error (m)", WRONG_M),
                                  (axes[1], "heading_error_deg", "heading error (deg)", WRONG_HEADING_DEG)):
        groups: dict[str, list[float]] = {}
        for r in rows:
            if str(r["table"]) not in ("4", "5", "6"):
                continue
            name = f"T{r['table']} {r['preset']}"
            groups.setdefault(name, [])
            groups[name].append(_f(r.get(col)) if r.get(col) not in ("", None) else math.inf)
        for name, vals in sorted(groups.items()):
            v = np.sort(np.array(vals, dtype=float))
            frac = np.arange(1, v.size + 1) / v.size
            fin = np.isfinite(v)
            preset = name.split()[1]
            ls = {"T4": "-", "T5": "--", "T6": ":"}[name.split()[0]]
            ax.step(np.maximum(v[fin], 1e-3), frac[fin], where="post", ls=ls, color=COLORS.get(preset, "k"),
                    label=f"{name} (n={v.size}, {np.sum(~fin)} no fix)")
        ax.axvline(limit, color="k", lw=0.8, ls=":")
        ax.set_xscale("log")
        ax.set_xlabel(label + " (log); dotted: the 'wrong fix' limit")
        ax.set_ylabel("share of cases")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="lower right")
    fig.suptitle("error CDFs per look (T4 level, T5 tilted, T6 NavCam acquisitions); a case without fix counts as "
                 "an infinite error", fontsize=9)
    fig.tight_layout()
    return fig


def _calibration_figure(rows: list[dict]):
    plt = _plt()
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 4.4), gridspec_kw={"width_ratios": [1.3, 1]})
    for st, color in STATUS_COLORS.items():
        pts = [(max(_f(r["sigma_x_m"]), _f(r["sigma_y_m"])), _f(r["error_m"])) for r in rows
               if r.get("status") == st and r.get("sigma_x_m") not in ("", None)]
        if pts:
            s, e = np.array(pts).T
            ax.scatter(np.maximum(s, 1e-2), np.maximum(e, 1e-2), s=14, color=color, alpha=0.8,
                       label=f"{st} ({len(pts)})")
    lim = np.array([1e-2, 1e4])
    ax.plot(lim, lim, "k-", lw=0.8, label="error = sigma")
    ax.plot(lim, 2.45 * lim, "k--", lw=0.8, label="error = 2.45 sigma (95 % in 2-D)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlim(1e-2, 1e4)
    ax.set_ylim(1e-2, 1e4)
    ax.set_xlabel("reported sigma, larger axis (m)")
    ax.set_ylabel("actual position error (m)")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    ax.set_title("confidence calibration: points far above the dashed line are over-confident", fontsize=9)
    cats = ["ok", "ambiguous", "failed", "no_fix"]
    right = [sum(1 for r in rows if (r.get("status") or "no_fix") == c and str(r.get("wrong")) == "0") for c in cats]
    wrong = [sum(1 for r in rows if (r.get("status") or "no_fix") == c and str(r.get("wrong")) == "1") for c in cats]
    nofix = [sum(1 for r in rows if (r.get("status") or "no_fix") == c and str(r.get("wrong")) not in ("0", "1"))
             for c in cats]
    x = np.arange(len(cats))
    ax2.bar(x - 0.27, right, 0.27, color="#2ca02c", label="right fix")
    ax2.bar(x, wrong, 0.27, color="#d62728", label=f"wrong fix (> {WRONG_M:g} m or > {WRONG_HEADING_DEG:g} deg)")
    ax2.bar(x + 0.27, nofix, 0.27, color="#999999", label="no fix (no skyline)")
    ax2.set_xticks(x, cats)
    ax2.set_ylabel("cases")
    ax2.legend(fontsize=7)
    ax2.set_title("status against correctness: a wrong fix should never be 'ok'", fontsize=9)
    fig.tight_layout()
    return fig


def _extraction_figure(rows: list[dict]):
    plt = _plt()
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 3.8))
    groups: dict[str, list[dict]] = {}
    for r in rows:
        if r.get("kind") in ("panorama", "acquisition") and r.get("kept_fraction") not in ("", None):
            groups.setdefault(f"T{r['table']} {r['preset']}", []).append(r)
    names = sorted(groups)
    if names:
        ax.boxplot([[_f(r["kept_fraction"]) for r in groups[n]] for n in names])
        ax2.boxplot([[max(_f(r["extract_median_abs_err_deg"]), 1e-3) for r in groups[n]] for n in names])
        for a in (ax, ax2):
            a.set_xticks(np.arange(1, len(names) + 1), names)
    ax.set_ylabel("kept azimuths / seen")
    ax2.set_ylabel("median |extracted - true| (deg, log)")
    ax2.set_yscale("log")
    for a in (ax, ax2):
        a.tick_params(axis="x", labelrotation=30, labelsize=7)
        a.grid(alpha=0.3)
    fig.suptitle("skyline extraction against the ray-marched true horizon", fontsize=9)
    fig.tight_layout()
    return fig


def _overlay_figure(row: dict, folder: Path, truth_el: np.ndarray, n_azimuth: int):
    """Extracted, true and matched skylines in the mast frame at the true pose (degrees)."""
    from render_service.campaign.scoring import true_skyline  # noqa: PLC0415

    plt = _plt()
    fig, ax = plt.subplots(figsize=(12, 3.2))
    theta = np.arange(n_azimuth) * 360.0 / n_azimuth
    levelled = row.get("kind") == "acquisition"
    p = 0.0 if levelled else _f(row.get("pitch_deg")) or 0.0
    rr = 0.0 if levelled else _f(row.get("roll_deg")) or 0.0
    truth = true_skyline(truth_el, heading_deg=_f(row["true_heading_deg"]), pitch_deg=p, roll_deg=rr,
                         n_azimuth=n_azimuth)
    ax.plot(theta, truth, "k-", lw=1.2, label="true horizon (ray-marched at the true pose)")
    arr = folder / "arrays.npz"
    if arr.is_file():
        with np.load(arr) as z:
            if "skyline_deg" in z:
                sky = z["skyline_deg"]
                th = np.arange(sky.size) * 360.0 / sky.size
                ax.plot(th, sky, "r.", ms=3, label="extracted (kept samples)")
            if "db_skyline_deg" in z and "fix_pose" in z:
                db = z["db_skyline_deg"]
                x, y, h, fp, fr, off, start = z["fix_pose"]
                az = start + np.arange(db.size) * 360.0 / db.size
                rel = np.mod(az - h, 360.0)
                order = np.argsort(rel)
                ax.plot(rel[order], db[order] + off, "b-", lw=0.8, alpha=0.7,
                        label="database at the fix (level, shifted by the fitted heading)")
    ax.set_xlim(0, 360)
    ax.set_xlabel("azimuth from the true heading (deg)")
    ax.set_ylabel("elevation (deg)")
    ax.legend(fontsize=7, loc="upper right")
    ax.grid(alpha=0.3)
    ax.set_title(f"{row['case_id']}: error {row.get('error_m') or '-'} m, heading error "
                 f"{row.get('heading_error_deg') or '-'} deg, status {row.get('status')}, "
                 f"{row.get('reason') or ''}"[:160], fontsize=8)
    fig.tight_layout()
    return fig


def _table(headers: list[str], body: list[list]) -> str:
    h = "".join(f"<th>{html.escape(str(x))}</th>" for x in headers)
    rows = "".join("<tr>" + "".join(f"<td>{html.escape(str(x))}</td>" for x in r) + "</tr>" for r in body)
    return f"<table><thead><tr>{h}</tr></thead><tbody>{rows}</tbody></table>"


def _g(v, spec=".2f"):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return format(v, spec)


def _groups_table(summary: dict) -> str:
    from render_service.campaign.runner import screen_summary  # noqa: PLC0415

    refs = {ln.split()[0]: ln.split("  ")[-1] for ln in screen_summary(summary)
            if ln.split() and ln.split()[0] in summary["groups"]}
    body = []
    for key, g in summary["groups"].items():
        st = g["status"]
        body.append([key, g["cases"], _g(g["skyline_returned"], ".0%"), _g(g["kept_fraction"]["median"], ".0%"),
                     _g(g["extract_median_abs_err_deg"]["median"], ".3f"), _g(g["kept_samples_gt1deg_share"], ".2%"),
                     _g(g["error_m"]["median"]), _g(g["error_m"]["p90"]), _g(g["error_m"]["max"], ".1f"),
                     f"{g.get('beyond_5m_1deg', '-')} ({g.get('beyond_5m_1deg_floor_limited', '-')})",
                     _g(g["heading_error_deg"]["median"]),
                     _g(g["heading_error_deg"]["max"]),
                     f"{st.get('ok', 0)}/{st.get('ambiguous', 0)}/{st.get('failed', 0)}/{st.get('no_fix', 0)}",
                     f"{g['wrong']} ({g['wrong_ok']} ok)", _g(g["right_flagged_share"], ".0%"),
                     _g(g["locate_s"]["median"]), refs.get(key, "")])
    return _table(["group", "cases", "skyline returned", "kept/seen (median)", "extraction error (median deg)",
                   "kept samples > 1 deg", "error median (m)", "p90 (m)", "max (m)",
                   "beyond 5 m / 1 deg (floor-limited)", "heading median (deg)", "heading max (deg)",
                   "ok/amb/fail/no fix", "wrong (reported ok)", "right flagged", "locate (s)",
                   "reference report"], body)


CSS = """body{font-family:sans-serif;margin:1.5em;max-width:1400px;color:#222}
table{border-collapse:collapse;font-size:12px;margin:0.5em 0}
td,th{border:1px solid #bbb;padding:2px 6px;text-align:right}
th{background:#eee}td:first-child{text-align:left}img{max-width:100%}h2{border-bottom:1px solid #ccc}
.note{color:#555;font-size:13px}"""


def write_report(out: Path, rows: list[dict], summary: dict, ctx, truths: np.ndarray) -> Path:
    """Write ``out/report.html`` (atomically); returns its path."""
    c, r = summary["campaign"], summary["run"]
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>skyloc campaign {html.escape(c['profile'])}"
             f"</title><style>{CSS}</style></head><body>",
             f"<h1>skyloc campaign: profile {html.escape(c['profile'])}, seed {c['seed']}</h1>",
             "<p class='note'>DEM " + html.escape(str(c["dem"])) + f" ({html.escape(c['body'])}, sha256 "
             f"{c['dem_sha256'][:16]}), site {c['site']['area_m']:g} x {c['site']['area_m']:g} m at "
             f"{c['site']['step_m']:g} m centred on ({c['site']['center_x']:.1f}, {c['site']['center_y']:.1f}) "
             f"(metres, the DEM's metric CRS); {c['poses']} hidden poses off the grid, {len(c['rejected_poses'])} "
             f"rejected for a flat horizon; {c['rows']} of {c['cases']} cases finished; wall {r['wall_s']:.0f} s, "
             f"CPU {r['cpu_s_main'] + r['cpu_s_workers']:.0f} s, peak RSS main {r['peak_rss_mb_main']:.0f} MB, "
             f"workers {r['peak_rss_mb_workers']} MB; versions {html.escape(str(r['versions']))}.</p>",
             "<h2>How to read this page</h2><p class='note'>Every case renders what a rover would see at a hidden "
             "pose (Blender), extracts its skyline, matches it against the skyline database and compares the fix "
             "with the truth from the simulator's manifest (never with the fix's own estimate). Groups: "
             "T4 level panoramas per look (binary = the report's noise level 1, realistic = 2, distorted = 3, clean "
             "= no rocks, clear sky); T5 10 degrees of pitch or roll; T6 NavCam pan-tilt acquisitions (frames -> "
             "panorama -> skyline -> fix); T7 end of traverse (a 1 m window database around a prior up to 20 m "
             "off); T8 heading-only mode with the position prior off by d metres and the heading prior within 10 "
             f"degrees. A fix is wrong beyond {WRONG_M:g} m or {WRONG_HEADING_DEG:g} degrees; a wrong fix reported "
             "'ok' is the failure that matters most. Extraction columns compare the kept skyline samples with the "
             "ray-marched true horizon at the true pose.</p>",
             "<h2>Tables beside the reference report</h2>", _groups_table(summary),
             "<p class='note'>The report's figures (its tables 4-8) are for 3 poses (T4), 3 poses (T5, binary only), "
             "one acquisition (T6-T8); its T8 offsets were dx = dy = d. Floor-limited: a case whose pose's true "
             "horizon, located lost in space against the database, lands beyond 2.5 m or not ok (the site or the "
             "database limits it, not the image chain).</p>"]
    if rows:
        parts += ["<h2>Error CDFs</h2>", f"<img src='{_png(_cdf_figure(rows))}'>",
                  "<h2>Confidence calibration</h2>", f"<img src='{_png(_calibration_figure(rows))}'>",
                  "<h2>Extraction against the true horizon</h2>", f"<img src='{_png(_extraction_figure(rows))}'>"]
        ranked = sorted((x for x in rows if x.get("kind") in ("panorama", "acquisition", "window")),
                        key=lambda x: (-(_f(x.get("error_m")) if x.get("error_m") not in ("", None) else math.inf)))
        worst = ranked[:N_WORST]
        parts.append(f"<h2>The {len(worst)} worst cases</h2>")
        for w in worst:
            folder = out / "cases" / w["case_id"]
            parts.append(f"<h3>{html.escape(w['case_id'])}</h3><p class='note'>true ({w['true_x']}, {w['true_y']}) "
                         f"heading {w['true_heading_deg']}; fix ({w.get('fix_x') or '-'}, {w.get('fix_y') or '-'}) "
                         f"heading {w.get('fix_heading_deg') or '-'}; status {html.escape(str(w.get('status')))}; "
                         f"{html.escape(str(w.get('reason') or ''))}</p>")
            png = _file_png(folder / "locate.png")
            if png:
                parts.append(f"<img src='{png}'>")
            parts.append(f"<img src='{_png(_overlay_figure(w, folder, truths[int(w['pose'])], ctx.n_azimuth))}'>")
    if c["rejected_poses"]:
        parts += ["<h2>Rejected poses</h2>",
                  _table(["candidate", "x", "y", "relief (deg)", "reason"],
                         [[p["index"], f"{p['x']:.1f}", f"{p['y']:.1f}", p["relief_deg"], p["reason"]]
                          for p in c["rejected_poses"]])]
    parts.append("</body></html>")
    from board.atomic import write_text_atomic  # noqa: PLC0415

    return write_text_atomic(out / "report.html", "\n".join(parts))
