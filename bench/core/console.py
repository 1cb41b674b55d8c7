"""The console bench prints its tables to (rich, imported only when something is printed).

On a terminal it is the terminal's width, and rich fits each table into it. Anywhere else (a pipe, a file, a CI
log) no width limits the text: a table is as wide as its content, so no name is cut (`damping~from(calib…`), no
interval is wrapped over two lines, and a sentence stays on one line for whoever reads the file to wrap.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rich.console import Console

PLAIN_WIDTH = 100_000  # not a terminal: wider than any table or line bench prints


def table_console(stderr: bool = False) -> Console:
    """A rich Console on stdout (stderr with `stderr`): the terminal's width, or `PLAIN_WIDTH` when not a terminal."""
    from rich.console import Console  # rich: loaded only when something is printed

    here = Console(stderr=stderr)
    return here if here.is_terminal else Console(stderr=stderr, width=PLAIN_WIDTH)
