"""Skyline-database renderers sharing the ``render_tile(terrain, tile, spec)`` API."""
