"""Does a query come from the terrain, CRS and body a skyline database was rendered from?

A skyline matched against a database of another DEM, CRS or body still gives a pose (the best of
wrong places); the only defence is to compare what both say about their origin.  The database
carries its DEM's SHA-256, its grid CRS and its body (:class:`board.skydb.SkyDBMeta`); a query says
what it knows: an acquisition through its manifest (``meta.dem_sha256``, ``truth.crs``,
``meta.body``), a skyline through its ``meta`` (``dem_sha256``, ``crs_wkt``, ``body``).
Unknown fields are not compared.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from board.skydb import SkyDBMeta


@dataclass(frozen=True)
class Provenance:
    """What a query says about its origin ("" when unknown): DEM SHA-256, CRS (WKT), body name."""

    dem_sha256: str = ""
    crs_wkt: str = ""
    body: str = ""

    @classmethod
    def from_meta(cls, meta: dict, *, crs_wkt: str = "") -> Provenance:
        """From a skyline's or an acquisition's ``meta`` (keys ``dem_sha256``, ``crs_wkt``, ``body``)."""
        body = meta.get("body", "")
        return cls(str(meta.get("dem_sha256", "") or ""), str(meta.get("crs_wkt", "") or crs_wkt or ""),
                   str(body.get("name", "")) if isinstance(body, dict) else str(body or ""))

    @property
    def known(self) -> bool:
        return bool(self.dem_sha256 or self.crs_wkt or self.body)


def crs_name(wkt: str) -> str:
    """The name of a WKT CRS (its first quoted string), "" when none: 'WGS 84 / UTM zone 32N'."""
    m = re.search(r'^\s*[A-Z_]+\s*\[\s*"([^"]*)"', wkt or "")
    return m.group(1) if m else ""


def mismatches(db_meta: SkyDBMeta, query: Provenance) -> list[str]:
    """What differs between the database's origin and the query's: one sentence per field, [] when all agree.

    CRSs are compared by name (two WKT spellings of one CRS agree); bodies case-insensitively, and only
    when the database names one (not "custom").
    """
    out = []
    if query.dem_sha256 and db_meta.dem_sha256 and query.dem_sha256 != db_meta.dem_sha256:
        out.append(f"DEM: the query was made from DEM sha256 {query.dem_sha256[:12]}..., the database from "
                   f"{db_meta.dem_sha256[:12]}...")
    qn, dn = crs_name(query.crs_wkt), crs_name(db_meta.grid.crs_wkt)
    if qn and dn and qn != dn:
        out.append(f"CRS: the query is in {qn!r}, the database in {dn!r}")
    db_body = (db_meta.body or "").lower()
    if query.body and db_body and db_body != "custom" and query.body.lower() != db_body:
        out.append(f"body: the query is on {query.body}, the database on {db_meta.body}")
    return out
