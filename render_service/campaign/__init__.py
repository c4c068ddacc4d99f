"""``skyloc campaign``: the reference report's test campaign (its section 12, tables 4-8), end to end.

DEM -> skyline database -> simulated camera data at hidden poses (Blender panoramas of every look,
level and tilted, and NavCam pan-tilt acquisitions) -> panorama building -> skyline detection ->
matching -> errors against the truth in the manifests.  Everything random (site, positions off the
grid, headings, tilts, sun directions, texture seeds) is drawn from one seed; the heavy work runs on
the ground segment's Dask engine (:mod:`render_service.engine`); finished cases are recorded as they
end, so a killed run resumes without recomputing them.

Modules: :mod:`.profiles` (what each profile runs), :mod:`.reference` (the report's numbers),
:mod:`.planning` (site, poses and cases from the seed), :mod:`.tasks` (the Dask tasks),
:mod:`.scoring` (one row per case against the truth), :mod:`.ledger` (rows on disk, results.csv),
:mod:`.summary` (per-table aggregates), :mod:`.report_html` (report.html), :mod:`.runner` (the stages).
"""
from render_service.campaign.runner import CampaignOptions, run_campaign

__all__ = ["CampaignOptions", "run_campaign"]
