"""``tables.md`` and a self-contained ``report.html`` of an evaluation, beside the memorandum's tables.

Figures are PNGs embedded as base64 (no external file or script): per trajectory, the position error
against time, mean over trials with its 95 % t-band, one curve per mode (the memorandum's figs. 4-13).
"""
from __future__ import annotations

import base64
import html
import io
import math
from collections import defaultdict

import numpy as np

from . import memorandum as memo
from .stats import ROPE_PP, bayes_paired, cohens_d, improvement_percent, mean_band

LABEL = {"visible": "Vis", "thermal": "T-IR", "dual": "Dual", "visible-64": "Vis-64"}
PAIRS = memo.PAIRS + (("visible-64", "dual"),)


def _f(v: float, nd: int = 2) -> str:
    return "–" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{nd}f}"


def group(rows: list[dict]) -> dict:
    """{trajectory: {mode: {trial: row}}}."""
    g: dict = defaultdict(lambda: defaultdict(dict))
    for r in rows:
        g[int(r["trajectory"])][r["mode"]][int(r["trial"])] = r
    return g


def paired(g_traj: dict, a: str, b: str) -> tuple[np.ndarray, np.ndarray]:
    """E of modes a and b over the trials both have (paired by trial)."""
    trials = sorted(set(g_traj.get(a, {})) & set(g_traj.get(b, {})))
    return (np.array([g_traj[a][t]["E_percent"] for t in trials]),
            np.array([g_traj[b][t]["E_percent"] for t in trials]))


def compute_tables(rows: list[dict], modes: tuple[str, ...]) -> dict:
    """The three tables as data: t1[traj][mode] = mean E; t2[traj][pair] = (I, d); t3[traj][pair] = posterior."""
    g = group(rows)
    t1, t2, t3 = {}, {}, {}
    for k in sorted(g):
        t1[k] = {m: float(np.mean([r["E_percent"] for r in g[k][m].values()])) if g[k].get(m) else float("nan")
                 for m in modes}
        t2[k], t3[k] = {}, {}
        for a, b in PAIRS:
            if a in modes and b in modes:
                ea, eb = paired(g[k], a, b)
                if ea.size:
                    t2[k][(a, b)] = (improvement_percent(ea, eb), cohens_d(ea, eb))
                    t3[k][(a, b)] = bayes_paired(ea, eb)
    dual = [r["E_percent"] for r in rows if r["mode"] == "dual"]
    summary = {m: float(np.median([r["E_percent"] for r in rows if r["mode"] == m])) for m in modes
               if any(r["mode"] == m for r in rows)}
    avg_i = {}
    for a, b in PAIRS:
        vals = [t2[k][(a, b)][0] for k in t2 if (a, b) in t2[k]]
        if vals:
            avg_i[(a, b)] = float(np.mean(vals))
    return {"t1": t1, "t2": t2, "t3": t3, "median_E": summary, "avg_I": avg_i,
            "dual_median_E": float(np.median(dual)) if dual else float("nan")}


def tables_markdown(tables: dict, modes: tuple[str, ...], *, title: str = "") -> str:
    """Tables 1-3 in Markdown, ours then the memorandum's on the same rows."""
    out = [f"## {title}".rstrip(), ""] if title else []
    t1, t2, t3 = tables["t1"], tables["t2"], tables["t3"]
    memo_modes = ("visible", "thermal", "dual")
    out.append("### Table 1: mean E (%) per trajectory (ours | memorandum)")
    out.append("")
    out.append("| traj | " + " | ".join(LABEL[m] for m in modes) + " | memo " + " | memo ".join(
        LABEL[m] for m in memo_modes) + " |")
    out.append("|---" * (1 + len(modes) + 3) + "|")
    for k in sorted(t1):
        ours = " | ".join(_f(t1[k][m]) for m in modes)
        theirs = " | ".join(_f(v) for v in memo.TABLE1.get(k, (float("nan"),) * 3))
        out.append(f"| {k} | {ours} | {theirs} |")
    med = tables["median_E"]
    out.append("")
    out.append("Median E over all runs: " + ", ".join(f"{LABEL[m]} {_f(v)} %" for m, v in med.items()))
    out.append("")
    pairs = [p for p in PAIRS if any(p in t2[k] for k in t2)]
    out.append("### Table 2: improvement I (%) and Cohen's |d| (ours | memorandum)")
    out.append("")
    out.append("| traj | " + " | ".join(f"{LABEL[a]} vs {LABEL[b]} I | d" for a, b in pairs) + " | memo I/d (Vis-TIR, "
               "Vis-Dual, TIR-Dual) |")
    out.append("|---" * (2 + 2 * len(pairs)) + "|")
    for k in sorted(t2):
        cells = " | ".join(f"{_f(t2[k][p][0], 1)} | {_f(t2[k][p][1])}" if p in t2[k] else "– | –" for p in pairs)
        m2 = memo.TABLE2.get(k)
        theirs = ", ".join(f"{i:.1f}/{d:.2f}" for i, d in m2) if m2 else "–"
        out.append(f"| {k} | {cells} | {theirs} |")
    avg = tables["avg_I"]
    out.append("| avg | " + " | ".join(f"{_f(avg.get(p, float('nan')), 1)} | –" for p in pairs) + " | "
               + ", ".join(f"{v:.1f}" for v in memo.TABLE2_AVERAGE_I) + " |")
    out.append("")
    out.append(f"### Table 3: paired Bayesian t-test on E_a - E_b (pp): mode, 95 % HDI, % in ROPE +-{ROPE_PP} pp "
               "(ours | memorandum)")
    out.append("")
    out.append("| traj | pair | n | mode | HDI | % ROPE | memo mode | memo HDI | memo % ROPE |")
    out.append("|---|---|---|---|---|---|---|---|---|")
    for k in sorted(t3):
        for j, p in enumerate(pairs):
            if p not in t3[k]:
                continue
            po = t3[k][p]
            mt = memo.TABLE3.get(k)
            mrow = mt[memo.PAIRS.index(p)] if (mt and p in memo.PAIRS) else None
            theirs = (f"{mrow[0]:.3f} | [{mrow[1]:.3f}; {mrow[2]:.3f}] | {mrow[3]}" if mrow else "– | – | –")
            out.append(f"| {k} | {LABEL[p[0]]} vs {LABEL[p[1]]} | {po.n} | {_f(po.mode, 3)} | "
                       f"[{_f(po.hdi_lo, 3)}; {_f(po.hdi_hi, 3)}] | {_f(po.rope_percent, 0)} | {theirs} |")
    out.append("")
    return "\n".join(out)


def error_curves_png(rows: list[dict], trajectory: int, modes: tuple[str, ...]) -> bytes:
    """PNG of the mean position error vs time with 95 % bands, one curve per mode."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(6.4, 3.6), dpi=100)
    for m in modes:
        rs = [r for r in rows if int(r["trajectory"]) == trajectory and r["mode"] == m and "curve" in r]
        if not rs:
            continue
        n = min(len(r["curve"]["t"]) for r in rs)
        t = np.array(rs[0]["curve"]["t"][:n])
        c = np.array([r["curve"]["err_m"][:n] for r in rs])
        mean, half = mean_band(c)
        ax.plot(t, mean, label=f"{LABEL[m]} (n={len(rs)})")
        ax.fill_between(t, mean - np.nan_to_num(half), mean + np.nan_to_num(half), alpha=0.2)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("position error (m)")
    ax.set_title(f"trajectory {trajectory}: mean error, 95 % band")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()


def _md_table_to_html(md: str) -> str:
    """Minimal Markdown (headings, pipe tables, paragraphs) to HTML, escaped."""
    out, in_table = [], False
    for line in md.splitlines():
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            if all(set(c) <= set("-: ") for c in cells):
                continue
            tag = "th" if not in_table else "td"
            if not in_table:
                out.append("<table>")
                in_table = True
            out.append("<tr>" + "".join(f"<{tag}>{html.escape(c)}</{tag}>" for c in cells) + "</tr>")
            continue
        if in_table:
            out.append("</table>")
            in_table = False
        if line.startswith("### "):
            out.append(f"<h3>{html.escape(line[4:])}</h3>")
        elif line.startswith("## "):
            out.append(f"<h2>{html.escape(line[3:])}</h2>")
        elif line.strip():
            out.append(f"<p>{html.escape(line)}</p>")
    if in_table:
        out.append("</table>")
    return "\n".join(out)


def report_html(rows: list[dict], tables_md: str, modes: tuple[str, ...], header: dict) -> str:
    """The self-contained HTML report."""
    figs = []
    for k in sorted({int(r["trajectory"]) for r in rows}):
        b64 = base64.b64encode(error_curves_png(rows, k, modes)).decode("ascii")
        figs.append(f'<figure><img alt="trajectory {k} error vs time" src="data:image/png;base64,{b64}">'
                    f"<figcaption>Trajectory {k}: position error vs time, mean over trials and its 95 % "
                    "band (cf. the memorandum's figs. 4-13).</figcaption></figure>")
    meta = "".join(f"<li><b>{html.escape(str(k))}</b>: {html.escape(str(v))}</li>" for k, v in header.items())
    return ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>skyloc descent evaluation</title><style>"
            "body{font-family:sans-serif;max-width:1100px;margin:2em auto}table{border-collapse:collapse;"
            "margin:1em 0;font-size:13px}td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}"
            "figure{display:inline-block;margin:0.5em}</style></head><body>"
            "<h1>Descent navigation: the memorandum's evaluation</h1>"
            f"<ul>{meta}</ul>{_md_table_to_html(tables_md)}<h2>Error against time</h2>{''.join(figs)}"
            "</body></html>")
