"""One progress-bar helper for every long operation (imports, generation, caching, grids,
tuning). Lightning draws its own bar for training epochs."""

from __future__ import annotations

import sys
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from typing import Any

__all__ = ["ProgressBar", "progress_bar"]


class ProgressBar:
    """What :func:`progress_bar` yields. Call it to advance (``bar()`` or ``bar(n)``);
    :meth:`update` also sets the position and the extra fields. Disabled, it does nothing."""

    def __init__(self, bar: Any = None, task: Any = None) -> None:
        self._bar = bar
        self._task = task

    def __call__(self, n: int = 1) -> None:
        if self._bar is not None:
            self._bar.advance(self._task, n)

    def update(self, *, completed: int | None = None, advance: int = 0, **fields: Any) -> None:
        """Set the number done (``completed``) or add to it (``advance``), and set fields."""
        if self._bar is not None:
            self._bar.update(self._task, completed=completed, advance=advance, **fields)


@contextmanager
def progress_bar(
    description: str,
    total: int | None,
    enabled: bool = True,
    *,
    fields: Mapping[str, Any] | None = None,
    fields_format: str = "",
    eta: bool = True,
) -> Iterator[ProgressBar]:
    """A rich bar on stderr for the duration of the ``with`` block.

    Args:
        total: the number of steps, or None when unknown.
        enabled: False gives a bar that does nothing (``--no-progress``, workers, tests).
        fields: extra values shown after the count, with their start values.
        fields_format: how to show them, a rich format string using
            ``{task.fields[NAME]}`` (e.g. ``"best {task.fields[best]}"``).
    """
    if not enabled:
        yield ProgressBar()
        return
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns: list[Any] = [
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
    ]
    if fields_format:
        columns.append(TextColumn(fields_format))
    columns.append(TimeElapsedColumn())
    if eta:
        columns += [TextColumn("eta"), TimeRemainingColumn()]
    with Progress(*columns, console=Console(file=sys.stderr), transient=False) as bar:
        yield ProgressBar(bar, bar.add_task(description, total=total, **dict(fields or {})))
