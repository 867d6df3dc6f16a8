"""Progress bars on stderr when it is a terminal (and not --quiet); nothing in pipes and CI logs."""

from __future__ import annotations

import logging
import sys

import click

from .console import console


class NoBar:
    """What :func:`progress` gives where no bar is shown: the calls a bar takes, doing nothing."""

    current_item = None

    def update(self, n: int, current_item=None) -> None:
        pass

    def render_progress(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        pass


def progress(total: int | None, label: str, rate_label=None, show_eta: bool = True):
    """A progress bar on stderr when it is a terminal (and not --quiet); silent in pipes and CI logs."""
    if not sys.stderr.isatty() or not console.isEnabledFor(logging.INFO):
        return NoBar()
    return click.progressbar(length=total or 0, label=label, file=sys.stderr, show_pos=True, show_eta=show_eta,
                             item_show_func=rate_label or (lambda _: None))
