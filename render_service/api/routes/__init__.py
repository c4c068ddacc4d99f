"""Routers: health, DEM uploads, jobs and the HTML status page."""
