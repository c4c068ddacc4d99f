"""The one progress protocol of skyloc's long operations, and its terminal bar.

Every long operation (database rendering, matching, ``sim acquire``, ``sim dataset``) takes an
optional ``progress`` callable and calls it as ``progress(done, total, message)``: ``done`` units out
of ``total`` (tiles, positions, frames, acquisitions), ``message`` a short note of the current step
("" when none).  Library code never prints; the CLI turns the calls into a tqdm bar
(:func:`progress_bar`), Blender into its window-manager progress, the service into job fields.
Callers written for two arguments (``progress(done, total)``) are called the same way: the message
has a default.
"""
from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from typing import Protocol


class Progress(Protocol):
    """``progress(done, total, message="")``: ``done`` of ``total`` units finished; ``message`` the current step."""

    def __call__(self, done: int, total: int, message: str = "") -> None: ...


def report(progress: Progress | None, done: int, total: int, message: str = "") -> None:
    """Call ``progress`` when there is one (keeps the ``if progress is not None`` out of library loops)."""
    if progress is not None:
        progress(done, total, message)


@contextlib.contextmanager
def progress_bar(desc: str, *, unit: str = "it", file=None, disable: bool | None = None) -> Iterator[Progress]:
    """A :class:`Progress` drawing a tqdm bar on ``file`` (stderr); closed on exit.

    disable : None (default) shows the bar only when ``file`` is a terminal, so captured output
    (tests, pipes, logs) stays clean; True / False force it off / on.
    """
    from tqdm import tqdm  # noqa: PLC0415 - the CLI's dependency, not the library's

    out = sys.stderr if file is None else file
    if disable is None:
        disable = not (hasattr(out, "isatty") and out.isatty())
    bar = tqdm(total=None, desc=desc, unit=unit, file=out, disable=disable, dynamic_ncols=True)

    def update(done: int, total: int, message: str = "") -> None:
        if bar.total != total:
            bar.total = total
        bar.n = done
        if message:
            bar.set_postfix_str(message, refresh=False)
        bar.refresh()

    try:
        yield update
    finally:
        bar.close()
