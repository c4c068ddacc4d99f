"""Error hierarchy shared by every skyloc package (rasterio style).

Each error also inherits the matching builtin so callers can catch either.
Messages name the problem and the fix.
"""
from __future__ import annotations


class SkylocError(Exception):
    """Root of every error skyloc raises on purpose."""

    code: str = "skyloc_error"


class InvalidInputError(SkylocError, ValueError):
    """An argument, file or request is invalid; the message says how to fix it."""

    code = "invalid_input"


class DemReadError(SkylocError, OSError):
    """A DEM could not be read (missing, corrupt, unsupported)."""

    code = "dem_read_error"


class CrsError(InvalidInputError):
    """A CRS is missing, in degrees without a known body, or otherwise unusable."""

    code = "crs_error"


class NoDataError(InvalidInputError):
    """Too much missing data in the area of interest."""

    code = "nodata_error"


class FormatError(SkylocError, ValueError):
    """A skyloc file (database, skyline, acquisition) is corrupt or of an unknown version."""

    code = "format_error"


class NoSkylineError(SkylocError):
    """No skyline could be detected (all sky, all ground, over-exposed...)."""

    code = "no_skyline"


class JobNotFoundError(SkylocError, KeyError):
    """A render-service job id does not exist."""

    code = "job_not_found"
