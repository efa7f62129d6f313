"""What every stage's command line shares: one error style (``fail``), the consoles, progress lines for a log, the
option types (``SEED``, ``Finite``, ``Counted``, ``Metres``, ``Bounds``) and options (``--root``, ``--ray-address``),
and tables as text. The command groups that load the stages are ``uavplace.cli``'s."""

from __future__ import annotations

import math
import shlex
import sys
import time
from pathlib import Path
from typing import NoReturn

import click
from rich.console import Console
from rich.markup import escape
from rich.table import Table
from rich.text import Text

from uavplace.infra.files import DEFAULT_ROOT, describe_os_error
from uavplace.infra.limits import limits, over_limit
from uavplace.schemas import InputError
from uavplace.schemas.base import MAX_SEED

console = Console(stderr=True)


def stdout() -> Console:
    """Console for results: the terminal's width, or 160 columns when piped (names stay whole)."""
    return Console(width=None if sys.stdout.isatty() else 160)


def say(line: str) -> None:
    """Print one result line as it is (no colouring of numbers, long lines wrapped by the terminal, not cut)."""
    stdout().print(line, highlight=False, soft_wrap=True)


#: Seconds between the plain progress lines long work prints when its output is not a terminal (a log).
LINE_SECONDS = 30.0


class LogLines:
    """Progress for a log: when results go to a file or a pipe (not a terminal) and not ``quiet``, long work prints a
    plain line at most every ``LINE_SECONDS``, plus every line marked ``last`` (a task's end); in a terminal, nothing
    (its progress bar or status line says it). ``enabled`` tells which."""

    def __init__(self, quiet: bool = False) -> None:
        self.enabled = not quiet and not stdout().is_terminal
        self._last = float("-inf")

    def __call__(self, text: str, last: bool = False) -> None:
        now = time.monotonic()
        if self.enabled and (last or now - self._last >= LINE_SECONDS):
            self._last = now
            stdout().print(text, highlight=False, markup=False, soft_wrap=True)


def warn_or_refuse(lines: list[str], strict: bool) -> None:
    """``lines`` (what a command found unlike what it expects) as one warning line each, or, with ``--strict``, a
    refusal (exit 2) naming the first."""
    if lines and strict:
        raise click.UsageError(f"--strict: {lines[0]}" + (f" (and {len(lines) - 1} more)" if len(lines) > 1 else ""))
    for line in lines:
        console.print(f"[yellow]warning:[/] {line} (--strict refuses)", highlight=False, soft_wrap=True)


def command_line() -> str:
    return " ".join(shlex.quote(a) for a in [Path(sys.argv[0]).name, *sys.argv[1:]])


#: ``--root``: where ingested cities and bundles live (shared by uavdata and uavrl commands).
root_option = click.option(
    "--root",
    type=click.Path(file_okay=False, path_type=Path),
    default=DEFAULT_ROOT,
    show_default=True,
    help="Root of processed data.",
)


def path_option(*decls: str, folder: bool, help: str, default: str | Path | None = None):  # noqa: A002, ANN201
    """An option naming a folder (``folder``) or a file as a ``Path``: ``decls`` as click takes them (the flag, then
    the parameter's name where it is not the flag's), ``default`` shown where there is one; one wording of the type
    for every command."""
    kind = click.Path(file_okay=not folder, dir_okay=folder, path_type=Path)
    given = None if default is None else Path(default)
    return click.option(*decls, type=kind, default=given, show_default=given is not None, help=help)


def folder_option(name: str, default: str, help: str):  # noqa: A002, ANN201 - click's word; a click decorator
    """``name`` (``--out``, ``--raw``): a folder, ``default`` shown."""
    return path_option(name, folder=True, default=default, help=help)


def ray_address_option(what: str):  # noqa: ANN201 - a click decorator
    """``--ray-address``: the Ray cluster ``what`` runs on (a local Ray by default), one wording for every command."""
    return click.option(
        "--ray-address",
        default=None,
        help=f"Ray cluster to run {what} on (e.g. ray://head:10001, or auto); default: a local Ray on this machine.",
    )


def fail(err: Exception | str) -> NoReturn:
    """Print one error line and exit with status 2."""
    text = describe_os_error(err) if isinstance(err, OSError) and not isinstance(err, InputError) else str(err)
    text = " ".join(text.split()) or type(err).__name__  # one line, whatever the message held
    console.print(f"[bold red]error:[/] {escape(text)}", highlight=False, soft_wrap=True)
    sys.exit(2)


def markdown_table(rows: list[list[str]]) -> str:
    """Text cells (header first) as a Markdown table."""
    escape = str.maketrans({"|": "\\|"})
    lines = ["| " + " | ".join(c.translate(escape) for c in rows[0]) + " |", "|" + "---|" * len(rows[0])]
    return "\n".join(lines + ["| " + " | ".join(c.translate(escape) for c in r) + " |" for r in rows[1:]])


def markdown_list(lines: list[str]) -> str:
    """Sentences as a Markdown list, one item each."""
    return "\n".join(f"- {line}" for line in lines)


def plain_table(*headers: str, rows: list[list[str]] = (), **kwargs) -> Table:  # noqa: ANN003 - rich.table.Table's options
    """A rich table whose headers, cells and title are text, not markup: units such as ``[m]``, intervals and names
    such as ``best [best-s0]`` stay visible; ``rows`` are added."""
    if isinstance(kwargs.get("title"), str):
        kwargs["title"] = Text(kwargs["title"])
    table = Table(**kwargs)
    for header in headers:
        table.add_column(Text(header))
    for row in rows:
        table.add_row(*(Text(c) if isinstance(c, str) else c for c in row))
    return table


def keep_whole(table: Table, *headers: str) -> Table:
    """``table`` with the columns ``headers`` never cut or wrapped (names and versions a user copies into a command):
    each as wide as its longest cell; the other columns give way."""
    for column in table.columns:
        if str(column.header) in headers:
            cells = [len(str(c)) for c in column.cells]
            column.no_wrap, column.min_width = True, max([len(str(column.header)), *cells])
    return table


#: The type of every ``--seed``: numpy's and torch's generators take a non-negative integer.
SEED = click.IntRange(0, MAX_SEED)


class Finite(click.FloatRange):
    """A finite number (``nan`` and ``inf`` refused: click's ``FloatRange`` lets ``nan`` through every bound),
    optionally within ``[min, max]``."""

    name = "number"

    def convert(self, value, param, ctx):  # noqa: ANN001, ANN201 - click's signature
        number = click.FLOAT.convert(value, param, ctx)
        if not math.isfinite(number):  # said before the range, which inf would fail for another reason
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return super().convert(number, param, ctx)

    def _describe_range(self) -> str:
        """The range as ``--help`` shows it: "finite" without bounds (click would write ``x<=None``)."""
        return "finite" if self.min is None and self.max is None else super()._describe_range()


class Counted(click.IntRange):
    """A count of at least ``min`` that is also bounded by the resource limit ``limit`` (``infra.limits``): the
    loop it drives is refused before it starts, with the way to raise the limit."""

    def __init__(self, limit: str, min: int = 1) -> None:  # noqa: A002 - click's name
        super().__init__(min=min)
        self.limit = limit

    def convert(self, value, param, ctx):  # noqa: ANN001, ANN201 - click's signature
        number = super().convert(value, param, ctx)
        if number > getattr(limits(), self.limit):
            self.fail(over_limit(self.limit, number, "value"), param, ctx)
        return number


class Metres(click.ParamType):
    """A finite length in metres: ``4``, ``4m`` or ``2.5 m``."""

    name = "metres"

    def convert(self, value, param, ctx):  # noqa: ANN001, ANN201 - click's signature
        text = value if isinstance(value, float | int) else str(value).strip().lower().removesuffix("m").strip()
        try:
            number = float(text)
        except ValueError:
            self.fail(f"{value!r} is not a length in metres (e.g. 4m, 2.5)", param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite length", param, ctx)
        return number


class Bounds(click.ParamType):
    """``auto``, ``receivers``, ``buildings`` or ``XMIN,YMIN,XMAX,YMAX`` in metres."""

    name = "bounds"

    def convert(self, value, param, ctx):  # noqa: ANN001, ANN201 - click's signature
        if value in ("auto", "receivers", "buildings") or isinstance(value, tuple):
            return value
        try:
            box = tuple(float(v) for v in str(value).split(","))
        except ValueError:
            box = ()
        if len(box) != 4 or not all(math.isfinite(v) for v in box):
            self.fail(f"{value!r}: expected auto, receivers, buildings or XMIN,YMIN,XMAX,YMAX (finite)", param, ctx)
        return box
