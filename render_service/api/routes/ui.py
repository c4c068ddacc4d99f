"""``GET /``: a small HTML status page (jobs with progress bars, one database skyline as inline SVG).

Authenticated like the API; a browser can log in with HTTP Basic (any user name, the token as password).
"""
from __future__ import annotations

import html
import logging
import math
import time
from pathlib import Path
from string import Template

import numpy as np
from fastapi import APIRouter, Depends
from fastapi.responses import HTMLResponse

from board.errors import SkylocError
from board.skydb import SkyDB
from render_service import __version__
from render_service.api.deps import get_runner, get_settings, get_store
from render_service.api.routes.jobs import job_out
from render_service.settings import ServiceSettings
from render_service.store import JobStore

log = logging.getLogger(__name__)
router = APIRouter(tags=["ui"])
_TEMPLATE = Template((Path(__file__).resolve().parents[2] / "templates" / "status.html").read_text())


def _row(j) -> str:
    frac = j.tiles_done / j.tiles_total if j.tiles_total else (1.0 if j.state == "done" else 0.0)
    rate = f"{j.positions_per_s:,.0f}" if j.positions_per_s else "&ndash;"
    eta = f"{j.eta_s:,.0f} s" if j.eta_s is not None else "&ndash;"
    e = html.escape
    return (f'<tr class="state-{e(j.state)}"><td><code>{e(j.id)}</code></td><td>{e(j.kind)}</td><td>{e(j.state)}</td>'
            f'<td><div class="bar" role="progressbar" aria-valuenow="{100 * frac:.0f}" aria-valuemin="0" '
            f'aria-valuemax="100"><div class="fill" style="width:{100 * frac:.1f}%"></div></div></td>'
            f"<td>{j.tiles_done} / {j.tiles_total}</td><td>{rate}</td><td>{eta}</td><td>{e(j.error or '')}</td></tr>")


#: conservative width of one character of the tick labels, in font sizes (digits, minus and degree sign are
#: about 0.55-0.6 em in common sans-serif fonts)
_CHAR_EM = 0.65
_TICK_FONT = 11


def _nice_ticks(lo: float, hi: float, n: int = 5) -> np.ndarray:
    """Round tick values (1, 2, 2.5 or 5 x 10^k apart) covering [lo, hi], about ``n`` of them."""
    raw = (hi - lo) / max(n - 1, 1)
    mag = 10.0 ** math.floor(math.log10(raw)) if raw > 0 else 1.0
    step = next(f * mag for f in (1.0, 2.0, 2.5, 5.0, 10.0) if f * mag >= raw)
    return np.arange(math.ceil(lo / step) * step, hi + step * 1e-9, step)


def _label_width(text: str, font_size: float = _TICK_FONT) -> float:
    return _CHAR_EM * font_size * len(text)


def skyline_svg(az_deg: np.ndarray, el_deg: np.ndarray, *, title: str, width: int = 720, height: int = 240) -> str:
    """Inline SVG of a skyline: elevation (degrees) against azimuth (degrees from grid north).

    The left margin is as wide as the longest elevation label (plus a gap), so no tick label is clipped by the
    SVG's edge whatever the elevations; ticks are round values.
    """
    ok = np.isfinite(el_deg)
    if not ok.any():
        return '<p class="muted">the skyline has no rendered samples</p>'
    lo, hi = float(np.nanmin(el_deg)), float(np.nanmax(el_deg))
    lo, hi = math.floor(min(lo, 0.0)) - 1, math.ceil(max(hi, 0.0)) + 1
    yvals = _nice_ticks(lo, hi)
    ylabels = [f"{v:g}\u00b0" for v in yvals]
    m = 40                                                    # right, top and bottom margins
    ml = max(m, math.ceil(max(_label_width(t) for t in ylabels)) + 14)   # left: labels + 6 px gap + 8 px edge

    def px(a):
        return ml + (a / 360.0) * (width - ml - m)

    def py(e):
        return height - m - (e - lo) / (hi - lo) * (height - 2 * m)

    f = _TICK_FONT
    pts = " ".join(f"{px(a):.1f},{py(e):.1f}" for a, e, k in zip(az_deg, el_deg, ok) if k)
    ticks = "".join(f'<text x="{px(a):.0f}" y="{height - m + 16}" font-size="{f}" text-anchor="middle">{a}&#176;</text>'
                    for a in range(0, 361, 45))
    yt = "".join(f'<text x="{ml - 6}" y="{py(v) + 4:.0f}" font-size="{f}" text-anchor="end">'
                 f'{html.escape(t).replace(chr(176), "&#176;")}</text>' for v, t in zip(yvals, ylabels))
    return (f'<svg id="skyline" xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
            f'viewBox="0 0 {width} {height}" font-family="sans-serif"><title>{html.escape(title)}</title>'
            f'<line x1="{ml}" y1="{py(0):.1f}" x2="{width - m}" y2="{py(0):.1f}" stroke="#bbb" stroke-dasharray="4 3"/>'
            f'<polyline fill="none" stroke="#3a7bd5" stroke-width="1.5" points="{pts}"/>{ticks}{yt}'
            f'<text x="{width / 2}" y="16" font-size="12" text-anchor="middle">{html.escape(title)}</text></svg>')


def _skyline_block(store: JobStore, settings: ServiceSettings) -> str:
    for job in store.list_jobs(limit=50, states=("done",)):
        if job.kind != "skyline_db":
            continue
        try:
            db = SkyDB.open(settings.jobs_dir / job.id / "db.zarr")
            i, j = db.grid.ny // 2, db.grid.nx // 2
            x, y = db.grid.xy(i, j)
            el = db.skyline(i, j)
        except SkylocError as exc:
            log.warning("status page: cannot read the database of job %s: %s", job.id, exc)
            continue
        title = f"job {job.id}: horizon at grid centre ({float(x):.1f}, {float(y):.1f}) m"
        return skyline_svg(db.meta.azimuths_deg(), el, title=title) + \
            '<p class="muted">elevation (degrees) against azimuth (degrees clockwise from grid north)</p>'
    return '<p class="muted">no finished skyline database yet</p>'


@router.get("/", response_class=HTMLResponse, summary="HTML status page")
def status_page(store: JobStore = Depends(get_store), settings: ServiceSettings = Depends(get_settings),
                runner=Depends(get_runner)) -> HTMLResponse:
    now = time.time()
    jobs = [job_out(j, now=now, runner=runner) for j in store.list_jobs(limit=100)]
    workers = runner.n_workers() if runner is not None else None
    page = _TEMPLATE.substitute(version=__version__, workers=workers if workers is not None else "&ndash;",
                                n_jobs=len(jobs), job_rows="\n".join(_row(j) for j in jobs) or
                                '<tr><td colspan="8" class="muted">no jobs yet</td></tr>',
                                skyline=_skyline_block(store, settings))
    return HTMLResponse(page)
