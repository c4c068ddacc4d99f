"""``skyloc descent eval``: the memorandum's evaluation of the descent filter (tables 1-3, figures 4-13).

``profiles`` names the protocols (``ci``, ``paper``); ``tasks`` is the Dask task of one trial (its
sequence from the simulator, then the filter in every mode on it: common random numbers);
``stats`` the per-trajectory statistics; ``report`` writes ``tables.md`` and ``report.html``;
``campaign.run_eval`` ties them together, resumably.
"""
