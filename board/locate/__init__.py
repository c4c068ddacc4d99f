"""Locate a rover from its skyline: the public matching API.

``locate(db, skyline, options)`` runs the exhaustive FFT search over the part of the database
the mode allows, refines the best candidates on the sphere (position between grid nodes,
heading, pitch, roll) and attaches a calibrated confidence.  Coordinates are metres in the
database's CRS; angles are degrees (azimuths clockwise from grid north).

Modules, by responsibility:

* :mod:`~board.locate.options` -- :class:`LocateOptions`, the typed options (and ablation switches);
* :mod:`~board.locate.orchestrator` -- :func:`locate`: coarse search, refinements, re-levelled search;
* :mod:`~board.locate.refinement` -- the refinement strategies (walk, multistart, weighted);
* :mod:`~board.locate.grid_error` -- the database's grid-error model;
* :mod:`~board.locate.window` -- database windows and position limits;
* :mod:`~board.locate.assemble` -- covariance and status of the fix (the policy is
  :func:`board.pose.confidence.fix_status`);
* :mod:`~board.locate.fix` -- :class:`Fix`, and :class:`FixPictures` for the plots.
"""
from board.locate.fix import Fix, FixPictures
from board.locate.options import MODES, LocateOptions
from board.locate.orchestrator import locate

__all__ = ["MODES", "Fix", "FixPictures", "LocateOptions", "locate"]
