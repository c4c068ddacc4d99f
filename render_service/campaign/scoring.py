"""One results row per case, scored against the truth of the manifests (never the fix's own estimate).

Truth: the pose drawn by the campaign (the same one the simulator wrote into the manifest's
ground truth) and the exact horizon ray-marched there at 0.1 degree (``TRUTH_N_AZIMUTH``).  The
true skyline of a panorama is that horizon seen in the mast's frame (tilted like the rover); an
acquisition's panorama is levelled with the manifest's attitude, so its true skyline is the level
one.  Angles in degrees, distances in metres.

Only the azimuths whose true horizon lies inside the picture are *seen* (:func:`view_limits`): a
NavCam acquisition's frames end some 30 degrees up, and a slope next to the rover can rise above
that.  A line kept where the horizon is out of the picture is wrong by definition: it counts among
the kept samples and among those more than 1 degree off (``kept_hidden_deg`` says how many).

A fix is *wrong* when it is more than ``WRONG_M`` (25 m) or ``WRONG_HEADING_DEG`` (2 degrees) off;
a wrong fix should never be ``ok`` and a right one should be.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from board.atomic import atomic_path
from board.conventions import wrap_deg180
from board.detect.preprocess import seen_or_all

#: A fix farther than this from the truth is wrong (metres), or with a heading error beyond (degrees).
WRONG_M = 25.0
WRONG_HEADING_DEG = 2.0

#: results.csv columns, in order (the issue's list first, then the harness's extras).
COLUMNS = (
    "table", "case_id", "dem", "preset", "mode", "pitch_deg", "roll_deg", "true_x", "true_y", "true_heading_deg",
    "fix_x", "fix_y", "fix_heading_deg", "error_m", "heading_error_deg", "status", "sigma_x_m", "sigma_y_m",
    "sigma_heading_deg", "seen_deg", "extract_status", "extract_s", "locate_s", "reason",
    "pose", "kind", "fix_pitch_deg", "fix_roll_deg", "prior_offset_m", "heading_prior_deg", "render_s", "case_s",
    "true_relief_deg", "off_grid_steps", "kept_deg", "kept_fraction", "extract_median_abs_err_deg",
    "extract_p90_abs_err_deg", "extract_frac_gt1deg", "ellipse95_major_m", "wrong", "wrong_ok", "right_flagged",
    "picture_error", "look", "kept_hidden_deg", "floor_error_m", "floor_status",
)

#: the cases located against the campaign's own database (the large-area lost cases have their own; the
#: robustness sets their own sites): they carry their pose's database floor
FLOOR_KINDS = ("panorama", "acquisition", "window", "heading")

#: the true horizon is "in the picture" at an azimuth when it lies this many panorama rows inside the seen
#: rows at least (the detector needs a few rows of sky and of ground); closer to the edge it is neither
#: counted as seen nor as hidden
VIEW_MARGIN_ROWS = 3


def _look_name(preset: str, body: str) -> str:
    """The name of the look rendered for ``preset`` on ``body`` (e.g. realistic -> realistic-moon)."""
    from blender_addon.core.degrade import look_on_body  # noqa: PLC0415
    from board.errors import InvalidInputError  # noqa: PLC0415

    try:
        return look_on_body(preset, body).name
    except InvalidInputError:  # not a look name: keep the preset's name
        return str(preset)


#: Columns that measure time (they differ between two runs of the same campaign).
TIME_COLUMNS = ("extract_s", "locate_s", "render_s", "case_s")


@dataclass
class CaseOutcome:
    """What the stages of a case produced (filled in as the case runs)."""

    case: dict
    cand: dict
    stage: str = "plan"
    reason: str = ""
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    render_s: float = float("nan")
    extract_s: float = float("nan")
    locate_s: float = float("nan")
    extract_status: str = ""
    levelled: bool = False
    skyline: object = None
    fix: object = None
    prior: tuple = field(default_factory=tuple)
    heading_prior_deg: float = float("nan")
    picture_error: str = ""
    view: tuple | None = None   # (top, bottom, margin) of the picture per skyline azimuth, see view_limits


def true_skyline(truth_el: np.ndarray, *, heading_deg: float, pitch_deg: float, roll_deg: float,
                 n_azimuth: int) -> np.ndarray:
    """The true skyline on the query grid (``n_azimuth`` samples from the heading), degrees."""
    from board.match.synthetic import observe  # noqa: PLC0415

    az = np.arange(truth_el.size) * 360.0 / truth_el.size
    return observe(az, truth_el, heading_deg=heading_deg, pitch_deg=pitch_deg, roll_deg=roll_deg, n=n_azimuth)


def view_limits(pano, n_azimuth: int, azimuth_start_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray, float]:
    """Where a panorama saw, on a skyline's azimuth grid: per azimuth (``n_azimuth`` samples from
    ``azimuth_start_deg``, the panorama's azimuth reference), the elevations of the highest and the lowest
    seen row (degrees, NaN where the column saw nothing), and the margin (degrees) of
    ``VIEW_MARGIN_ROWS`` rows."""
    g = pano.geometry
    seen = seen_or_all(pano.seen, (g.height, g.width))
    any_seen = seen.any(axis=0)
    first = np.argmax(seen, axis=0)
    last = seen.shape[0] - 1 - np.argmax(seen[::-1], axis=0)
    top = np.where(any_seen, g.el_of_row(first), np.nan)
    bottom = np.where(any_seen, g.el_of_row(last), np.nan)
    az = azimuth_start_deg + np.arange(n_azimuth) * 360.0 / n_azimuth
    col = np.rint(g.col_of_az(az)).astype(np.int64)
    if g.is_full_circle:
        col %= g.width
    inside = (col >= 0) & (col < g.width)
    col = np.clip(col, 0, g.width - 1)
    return (np.where(inside, top[col], np.nan), np.where(inside, bottom[col], np.nan),
            VIEW_MARGIN_ROWS * g.elevation_step_deg)


def extraction_errors(extracted: np.ndarray, truth: np.ndarray, step_deg: float, view: tuple | None = None) -> dict:
    """Seen arc, kept arc, its share of the seen arc and the errors of the kept samples against the truth
    (arcs in degrees of azimuth).

    view : ``(top, bottom, margin)`` from :func:`view_limits`, or None (every azimuth with a true horizon seen).
    With it, an azimuth is seen where the truth lies ``margin`` inside [bottom, top], hidden where it lies
    outside (or the column saw nothing); a sample kept where the horizon is hidden counts as kept and
    more than 1 degree off (``n_kept_hidden``)."""
    has = np.isfinite(truth)
    if view is None:
        seen, hidden = has, np.zeros_like(has)
    else:
        top, bottom, margin = view
        with np.errstate(invalid="ignore"):
            seen = has & (truth <= top - margin) & (truth >= bottom + margin)
            hidden = has & ~((truth <= top) & (truth >= bottom))   # NaN limits (nothing seen): hidden
    kept = np.isfinite(extracted) & seen
    kept_hidden = np.isfinite(extracted) & hidden
    err = np.abs(extracted[kept] - truth[kept])
    n_bad = int((err > 1.0).sum() + kept_hidden.sum())
    n_all = int(kept.sum() + kept_hidden.sum())
    return {
        "seen_deg": float(seen.sum() * step_deg),
        "kept_deg": float(kept.sum() * step_deg),
        "kept_fraction": float(kept.sum() / max(int(seen.sum()), 1)),
        "extract_median_abs_err_deg": float(np.median(err)) if err.size else float("nan"),
        "extract_p90_abs_err_deg": float(np.percentile(err, 90)) if err.size else float("nan"),
        "extract_frac_gt1deg": float(n_bad / n_all) if n_all else float("nan"),
        "n_kept": n_all,
        "n_gt1deg": n_bad,
        "n_kept_hidden": int(kept_hidden.sum()),
        "kept_hidden_deg": float(kept_hidden.sum() * step_deg),
    }


def _r(v, nd: int = 4):
    if v is None:
        return ""
    try:
        f = float(v)
    except (TypeError, ValueError):
        return v
    return "" if not math.isfinite(f) else round(f, nd)


def add_floor(rows: list[dict], floor: list[dict]) -> None:
    """Give every row of :data:`FLOOR_KINDS` (not of the robustness table) its pose's database floor, in place:
    ``floor_error_m`` (m) and ``floor_status`` of its true horizon located lost in space against the campaign's
    database (:func:`render_service.campaign.floor.floor_rows`, one row per accepted pose in order).  A case's
    error beyond its floor is the image chain's; a floor beyond the target is the site's or the database's."""
    for r in rows:
        k = r.get("pose")
        if not floor or r.get("table") == "R" or r.get("kind") not in FLOOR_KINDS or k in ("", None):
            continue
        f = floor[int(k)]
        r["floor_error_m"], r["floor_status"] = _r(f["error_m"]), f["status"]


def make_row(ctx, st: CaseOutcome, truth_el: np.ndarray | None) -> dict:
    """The results row of a case (see :data:`COLUMNS`); empty cells where a stage did not run
    (and the relief and extraction columns empty without ``truth_el``, the true horizon)."""
    from render_service.campaign.planning import (  # noqa: PLC0415
        Site,
        horizon_relief_deg,  # noqa: PLC0415
        off_grid_distance_steps,
    )

    c, cd = st.case, st.cand
    prof = ctx.profile
    site = Site(ctx.site_xy[0], ctx.site_xy[1], prof["area_m"], prof["step_m"], (0, 0, 0, 0))
    row: dict = {k: "" for k in COLUMNS}
    row.update({
        "table": c["table"], "case_id": c["case_id"], "dem": ctx.dem_spec, "preset": c["preset"],
        "mode": c["mode"], "pitch_deg": _r(st.pitch_deg), "roll_deg": _r(st.roll_deg), "true_x": _r(cd["x"], 3),
        "true_y": _r(cd["y"], 3), "true_heading_deg": _r(cd["heading_deg"]), "pose": c["pose"], "kind": c["kind"],
        "extract_status": st.extract_status, "extract_s": _r(st.extract_s), "render_s": _r(st.render_s, 2),
        "reason": st.reason, "picture_error": st.picture_error, "look": _look_name(c["preset"], ctx.body),
        "prior_offset_m": _r(st.prior[2] if st.prior else c.get("prior_offset_m", 0.0), 3),
        "heading_prior_deg": _r(st.heading_prior_deg),
        "true_relief_deg": "" if truth_el is None else _r(horizon_relief_deg(truth_el), 3),
        "off_grid_steps": _r(off_grid_distance_steps(cd["x"], cd["y"], site), 3),
    })
    if st.skyline is not None:
        sky = st.skyline
        # seen_deg: the arc where the true horizon is in the picture (from extraction_errors below; empty for
        # the rows that reuse another case's skyline).  Before session 32 it held the skyline's coverage
        # (kept_deg and kept_hidden_deg together): rows of older campaign folders keep that meaning.
        if c["kind"] in ("panorama", "acquisition") and truth_el is not None:
            tp, tr = (0.0, 0.0) if st.levelled else (st.pitch_deg, st.roll_deg)
            truth = true_skyline(truth_el, heading_deg=cd["heading_deg"], pitch_deg=tp, roll_deg=tr,
                                 n_azimuth=sky.n)
            ex = extraction_errors(sky.elevation_deg, truth, sky.azimuth_step_deg, st.view)
            row.update({k: _r(v) for k, v in ex.items() if k in COLUMNS})
            row["n_kept"], row["n_gt1deg"] = ex["n_kept"], ex["n_gt1deg"]
    fix = st.fix
    if fix is not None:
        err = math.hypot(fix.x - cd["x"], fix.y - cd["y"])
        herr = abs(float(wrap_deg180(fix.heading_deg - cd["heading_deg"])))
        wrong = err > WRONG_M or herr > WRONG_HEADING_DEG
        row.update({
            "fix_x": _r(fix.x, 3), "fix_y": _r(fix.y, 3), "fix_heading_deg": _r(fix.heading_deg),
            "fix_pitch_deg": _r(fix.pitch_deg), "fix_roll_deg": _r(fix.roll_deg), "error_m": _r(err),
            "heading_error_deg": _r(herr), "status": fix.status, "sigma_x_m": _r(fix.sigma_x_m),
            "sigma_y_m": _r(fix.sigma_y_m), "sigma_heading_deg": _r(fix.sigma_heading_deg),
            "locate_s": _r(st.locate_s), "ellipse95_major_m": _r(fix.ellipse95_m[0], 3),
            "wrong": int(wrong), "wrong_ok": int(wrong and fix.status == "ok"),
            "right_flagged": int((not wrong) and fix.status != "ok"),
        })
        if fix.status != "ok" and not row["reason"]:
            row["reason"] = f"locate: {fix.reason}"
    else:
        row["status"] = "no_fix"
    return row


def save_case_arrays(folder: Path, st: CaseOutcome) -> None:
    """Arrays for the report's pictures (the extracted skyline and, with a fix, the matched one)."""
    arrays: dict[str, np.ndarray] = {}
    if st.skyline is not None:
        arrays["skyline_deg"] = np.asarray(st.skyline.elevation_deg, dtype=np.float32)
    from render_service.campaign.tasks import fix_pictures  # noqa: PLC0415

    fix = st.fix
    if fix is not None and fix_pictures(fix, "db_skyline_deg") is not None:
        arrays["db_skyline_deg"] = np.asarray(fix_pictures(fix, "db_skyline_deg"), dtype=np.float32)
        arrays["fix_pose"] = np.array([fix.x, fix.y, fix.heading_deg, fix.pitch_deg, fix.roll_deg, fix.offset_deg,
                                       fix_pictures(fix, "db_azimuth_start_deg") or 0.0])
    if arrays:
        with atomic_path(folder / "arrays.npz", suffix=".part.npz") as tmp:
            np.savez_compressed(tmp, **arrays)
