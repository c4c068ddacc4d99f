"""One results row per case, scored against the truth of the manifests (never the fix's own estimate).

Truth: the pose drawn by the campaign (the same one the simulator wrote into the manifest's
ground truth) and the exact horizon ray-marched there at 0.1 degree (``TRUTH_N_AZIMUTH``).  The
true skyline of a panorama is that horizon seen in the mast's frame (tilted like the rover); an
acquisition's panorama is levelled with the manifest's attitude, so its true skyline is the level
one.  Angles in degrees, distances in metres.

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
    "picture_error", "look",
)
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


def true_skyline(truth_el: np.ndarray, *, heading_deg: float, pitch_deg: float, roll_deg: float,
                 n_azimuth: int) -> np.ndarray:
    """The true skyline on the query grid (``n_azimuth`` samples from the heading), degrees."""
    from board.match.synthetic import observe  # noqa: PLC0415

    az = np.arange(truth_el.size) * 360.0 / truth_el.size
    return observe(az, truth_el, heading_deg=heading_deg, pitch_deg=pitch_deg, roll_deg=roll_deg, n=n_azimuth)


def extraction_errors(extracted: np.ndarray, truth: np.ndarray, step_deg: float) -> dict:
    """Kept arc, its share of the seen arc and the errors of the kept samples against the truth."""
    seen = np.isfinite(truth)
    kept = np.isfinite(extracted) & seen
    err = np.abs(extracted[kept] - truth[kept])
    return {
        "kept_deg": float(kept.sum() * step_deg),
        "kept_fraction": float(kept.sum() / max(int(seen.sum()), 1)),
        "extract_median_abs_err_deg": float(np.median(err)) if err.size else float("nan"),
        "extract_p90_abs_err_deg": float(np.percentile(err, 90)) if err.size else float("nan"),
        "extract_frac_gt1deg": float(np.mean(err > 1.0)) if err.size else float("nan"),
        "n_kept": int(kept.sum()),
        "n_gt1deg": int((err > 1.0).sum()),
    }


def _r(v, nd: int = 4):
    if v is None:
        return ""
    try:
        f = float(v)
    except (TypeError, ValueError):
        return v
    return "" if not math.isfinite(f) else round(f, nd)


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
        row["seen_deg"] = _r(sky.coverage_deg, 2)
        if c["kind"] in ("panorama", "acquisition") and truth_el is not None:
            tp, tr = (0.0, 0.0) if st.levelled else (st.pitch_deg, st.roll_deg)
            truth = true_skyline(truth_el, heading_deg=cd["heading_deg"], pitch_deg=tp, roll_deg=tr,
                                 n_azimuth=sky.n)
            ex = extraction_errors(sky.elevation_deg, truth, sky.azimuth_step_deg)
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
