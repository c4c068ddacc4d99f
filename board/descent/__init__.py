"""Descent navigation for icy-moon landers: the descent-sequence format (``sequence``) and the filter.

``board.descent.sequence`` (issue 14) reads and writes the descent-sequence folders the simulator
produces; the other modules (issue 15) are the navigation filter that reads them.
"""
