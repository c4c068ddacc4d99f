"""Per-table aggregates of a campaign's rows (what ``summary.json`` and the report tables show).

Each group (a table and a look; table 5 also by tilt axis, table 8 by prior offset) gets: counts,
the share of skylines returned, kept arc and extraction errors against the true horizon, the
position and heading error (median, p90, max), counts by status, and the honesty of the status:
the share of wrong fixes flagged (not ``ok``) and of right fixes flagged; and the database floor of its
poses (their true horizons located against the database, :mod:`.floor`).  Metres and degrees.
"""
from __future__ import annotations

import math
from collections import defaultdict

import numpy as np

from render_service.campaign import reference


def _f(v) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return float("nan")
    return f


def _stats(values: list[float]) -> dict:
    a = np.array([v for v in values if math.isfinite(v)], dtype=float)
    if a.size == 0:
        return {"n": 0, "median": None, "p90": None, "max": None}
    return {"n": int(a.size), "median": round(float(np.median(a)), 4), "p90": round(float(np.percentile(a, 90)), 4),
            "max": round(float(a.max()), 4)}


def _share(num: int, den: int) -> float | None:
    return None if den == 0 else round(num / den, 4)


def group_key(row: dict) -> str:
    """The aggregate a row belongs to, e.g. ``4/realistic``, ``5/binary/pitch``, ``8/binary/d10``."""
    t = str(row["table"])
    if t == "5":
        axis = "pitch" if _f(row.get("pitch_deg")) not in (0.0,) and math.isfinite(_f(row.get("pitch_deg"))) else "roll"
        return f"5/{row['preset']}/{axis}"
    if t == "8":
        return f"8/{row['preset']}/d{_f(row.get('prior_offset_m')):g}"
    if t == "6":
        tilted = any(abs(_f(row.get(k)) or 0.0) > 0 for k in ("pitch_deg", "roll_deg"))
        return f"6/{row['preset']}" + ("/tilted" if tilted else "")
    return f"{t}/{row['preset']}"


def _floor_limited(row: dict) -> bool:
    """True when the row's pose has a database floor beyond 2.5 m or not ``ok``: its true horizon alone does
    not give a tight fix there (the site or the database limits the case, not the image chain)."""
    e = _f(row.get("floor_error_m"))
    return math.isfinite(e) and (e > 2.5 or row.get("floor_status") != "ok")


def aggregate(rows: list[dict]) -> dict:
    """Statistics of a group of rows."""
    n = len(rows)
    returned = [r for r in rows if r.get("extract_status") in ("ok", "degraded")]
    fixes = [r for r in rows if r.get("status") in ("ok", "ambiguous", "failed")]
    status = defaultdict(int)
    for r in rows:
        status[r.get("status") or "no_fix"] += 1
    wrong = [r for r in fixes if str(r.get("wrong")) == "1"]
    right = [r for r in fixes if str(r.get("wrong")) == "0"]
    n_kept = sum(int(_f(r.get("n_kept")) or 0) for r in returned if math.isfinite(_f(r.get("n_kept"))))
    n_bad = sum(int(_f(r.get("n_gt1deg")) or 0) for r in returned if math.isfinite(_f(r.get("n_gt1deg"))))
    within = lambda m, d: sum(1 for r in fixes if _f(r["error_m"]) <= m and _f(r["heading_error_deg"]) <= d)  # noqa: E731
    misses = [r for r in rows if not (_f(r.get("error_m")) <= 5.0 and _f(r.get("heading_error_deg")) <= 1.0)]
    return {
        "cases": n,
        "skyline_returned": _share(len(returned), n),
        "kept_fraction": _stats([_f(r.get("kept_fraction")) for r in returned]),
        "extract_median_abs_err_deg": _stats([_f(r.get("extract_median_abs_err_deg")) for r in returned]),
        "kept_samples_gt1deg_share": _share(n_bad, n_kept),
        "error_m": _stats([_f(r.get("error_m")) for r in fixes]),
        "heading_error_deg": _stats([_f(r.get("heading_error_deg")) for r in fixes]),
        "floor_error_m": _stats([_f(r.get("floor_error_m")) for r in rows]),
        "beyond_5m_1deg": len(misses),
        "beyond_5m_1deg_floor_limited": sum(1 for r in misses if _floor_limited(r)),
        "within_2.5m_0.5deg": _share(within(2.5, 0.5), n),
        "within_5m_1deg": _share(within(5.0, 1.0), n),
        "status": dict(sorted(status.items())),
        "wrong": len(wrong),
        "wrong_ok": sum(1 for r in wrong if r.get("status") == "ok"),
        "wrong_flagged_share": _share(sum(1 for r in wrong if r.get("status") != "ok"), len(wrong)),
        "right_flagged_share": _share(sum(1 for r in right if r.get("status") != "ok"), len(right)),
        "render_s": _stats([_f(r.get("render_s")) for r in rows]),
        "extract_s": _stats([_f(r.get("extract_s")) for r in rows]),
        "locate_s": _stats([_f(r.get("locate_s")) for r in rows]),
    }


def summarise(rows: list[dict]) -> dict:
    """``{"groups": {key: aggregate}, "tables": {table: aggregate}, "reference": the report's}``."""
    groups: dict[str, list[dict]] = defaultdict(list)
    tables: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        groups[group_key(r)].append(r)
        tables[str(r["table"])].append(r)
    return {
        "groups": {k: aggregate(v) for k, v in sorted(groups.items(), key=lambda kv: _sort_key(kv[0]))},
        "tables": {k: aggregate(v) for k, v in sorted(tables.items())},
        "reference": {"table4": reference.table4_summary(), "table5": reference.table5_summary(),
                      "table6": reference.TABLE6, "table7": reference.TABLE7,
                      "table8_simulated": reference.TABLE8_SIMULATED},
    }


def _sort_key(key: str):
    parts = key.split("/")
    order = {"binary": 0, "clean": 1, "realistic": 2, "distorted": 3}
    out = [int(parts[0]) if parts[0].isdigit() else 99]
    for p in parts[1:]:
        if p.startswith("d") and p[1:].replace(".", "", 1).isdigit():
            out.append(float(p[1:]))
        else:
            out.append(order.get(p, 9))
    return tuple(str(v).zfill(8) if isinstance(v, (int, float)) else v for v in out)


def markdown(summary: dict) -> str:
    """The groups of a summary as a markdown table beside the report's figures (``summary.md``)."""
    from render_service.campaign.runner import screen_summary  # noqa: PLC0415

    refs = {ln.split()[0]: ln.split("  ")[-1].strip() for ln in screen_summary(summary)
            if ln.split() and ln.split()[0] in summary["groups"]}

    def g(v, spec=".2f"):
        return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec)

    c = summary["campaign"]
    lines = [f"Campaign `{c['profile']}` seed {c['seed']} on `{c['dem']}` ({c['body']}, "
             f"sha256 {c['dem_sha256'][:12]}): "
             f"{c['poses']} poses ({len(c['rejected_poses'])} rejected for a flat horizon), {c['rows']} cases.", "",
             "| group | cases | skyline returned | kept/seen (median) | extraction error median (deg) | kept > 1 deg | "
             "error median (m) | p90 (m) | max (m) | beyond 5 m / 1 deg (floor-limited) | heading median (deg) | "
             "heading max (deg) | "
             "ok/amb/fail/no fix | wrong (ok) | right flagged | <= 2.5 m & 0.5 deg | <= 5 m & 1 deg | report |",
             "|" + " --- |" * 18]
    for key, a in summary["groups"].items():
        st = a["status"]
        lines.append(
            f"| {key} | {a['cases']} | {g(a['skyline_returned'], '.0%')} | {g(a['kept_fraction']['median'], '.0%')} | "
            f"{g(a['extract_median_abs_err_deg']['median'], '.3f')} | {g(a['kept_samples_gt1deg_share'], '.2%')} | "
            f"{g(a['error_m']['median'])} | {g(a['error_m']['p90'])} | {g(a['error_m']['max'], '.1f')} | "
            f"{a.get('beyond_5m_1deg', '-')} ({a.get('beyond_5m_1deg_floor_limited', '-')}) | "
            f"{g(a['heading_error_deg']['median'])} | {g(a['heading_error_deg']['max'])} | "
            f"{st.get('ok', 0)}/{st.get('ambiguous', 0)}/{st.get('failed', 0)}/{st.get('no_fix', 0)} | "
            f"{a['wrong']} ({a['wrong_ok']}) | {g(a['right_flagged_share'], '.0%')} | "
            f"{g(a['within_2.5m_0.5deg'], '.0%')} | "
            f"{g(a['within_5m_1deg'], '.0%')} | {refs.get(key, '')} |")
    fl = summary.get("floor") or {}
    if fl.get("n"):
        limited = ", ".join(str(i) for i in fl["limited_poses"])
        lines += ["", "Database floor (each pose's true horizon located lost in space against the database; "
                      "floor-limited: a case whose pose's floor is beyond 2.5 m or not ok): "
                      f"median {fl['error_m_median']:.2f} m, p90 {fl['error_m_p90']:.2f} m, "
                      f"max {fl['error_m_max']:.2f} m, "
                      f"{fl['ok']} of {fl['n']} ok" + (f"; limited poses: {limited}" if limited else "") + "."]
    r = summary["run"]
    lines += ["", f"Wall {r['wall_s']:.0f} s, CPU {r['cpu_s_main'] + r['cpu_s_workers']:.0f} s (main + workers), "
                  f"peak RSS main {r['peak_rss_mb_main']:.0f} MB, workers {r['peak_rss_mb_workers']} MB, "
                  f"load {r['load_avg']:.1f} at the end, {r['finished_utc']}."]
    return "\n".join(lines) + "\n"
