"""Path options and arguments as :class:`~pathlib.Path` (click callbacks); an empty one is refused."""

from __future__ import annotations

from pathlib import Path

import click


def as_path(ctx: click.Context, param: click.Parameter, value: str | None) -> Path | None:
    """A path option or argument as a Path; an empty one is refused (``Path('')`` would be ``.``)."""
    if value is None:
        return None
    if not value.strip():
        raise click.BadParameter("empty path", ctx=ctx, param=param)
    return Path(value)


def as_paths(ctx: click.Context, param: click.Parameter, value: tuple[str, ...]) -> tuple[Path, ...]:
    """Several path arguments as Paths; an empty one is refused, as by :func:`as_path`."""
    return tuple(p for p in (as_path(ctx, param, v) for v in value) if p is not None)
