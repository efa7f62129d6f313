"""The command-line contract every stage shares: the ``uavdata`` and ``uavrl`` groups, one error style, output helpers.

Each stage keeps its commands in its own package (``ingest/cli.py``, ``simulate/cli.py``,
``dataset/cli.py``, ``rl/cli.py``, ``eval/cli.py``). The groups here name them by import path and
load a command's module only when that command (or ``--help``) needs it, so that no stage imports
another for its command line, and ``uavdata ingest`` never loads the ray tracer.
"""

from __future__ import annotations

import importlib
import json
import math
import os
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

from uavplace.schemas import InputError
from uavplace.schemas.base import MAX_SEED
from uavplace.schemas.bundle import EMBEDDED_NOISE_DBM
from uavplace.schemas.export import SCHEMA_MODELS, json_schemas
from uavplace.schemas.files import DEFAULT_ROOT, describe_os_error
from uavplace.schemas.limits import ENV as LIMITS_ENV
from uavplace.schemas.limits import Limits, limits, over_limit, set_limits, shown

console = Console(stderr=True)


def stdout() -> Console:
    """Console for results: the terminal's width, or 160 columns when piped (names stay whole)."""
    return Console(width=None if sys.stdout.isatty() else 160)


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


class UavGroup(click.Group):
    """A click group whose every failure is one ``error: ...`` line and exit status 2, never a traceback.

    Bad input (``InputError``), usage errors, operating-system errors (a full
    disk, a permission) and, as a last resort, any other exception are caught
    here. ``UAVPLACE_DEBUG=1`` lets an unexpected exception through with its
    traceback, for bug reports. ``lazy`` maps a command name to ``"module:attribute"``,
    imported when the command is first asked for.
    """

    def __init__(self, *args, lazy: dict[str, str] | None = None, **kwargs) -> None:  # noqa: ANN002, ANN003 - click.Group's
        super().__init__(*args, **kwargs)
        self.lazy = dict(lazy or {})

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*super().list_commands(ctx), *self.lazy})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in self.lazy and cmd_name not in self.commands:
            module, _, attribute = self.lazy[cmd_name].partition(":")
            self.add_command(getattr(importlib.import_module(module), attribute), cmd_name)
        return super().get_command(ctx, cmd_name)

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):  # noqa: ANN001, ANN201
        try:
            rv = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except click.exceptions.Abort:
            fail("aborted")
        except click.UsageError as err:
            hint = f" (see '{err.ctx.command_path} --help')" if err.ctx is not None else ""
            fail(f"{err.format_message()}{hint}")
        except click.ClickException as err:
            fail(err.format_message())
        except InputError as err:
            fail(err)
        except OSError as err:
            fail(describe_os_error(err))
        except Exception as err:
            if os.environ.get("UAVPLACE_DEBUG"):
                raise
            fail(f"internal error ({type(err).__name__}: {err}); run again with UAVPLACE_DEBUG=1 for the traceback")
        if not standalone_mode:
            return rv
        sys.exit(rv if isinstance(rv, int) else 0)


#: The type of every ``--seed``: numpy's and torch's generators take a non-negative integer.
SEED = click.IntRange(0, MAX_SEED)


class Finite(click.FloatRange):
    """A finite number (``nan`` and ``inf`` refused: click's ``FloatRange`` lets ``nan`` through every bound),
    optionally within ``[min, max]``."""

    name = "number"

    def convert(self, value, param, ctx):  # noqa: ANN001, ANN201 - click's signature
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number

    def _describe_range(self) -> str:
        """The range as ``--help`` shows it: "finite" without bounds (click would write ``x<=None``)."""
        return "finite" if self.min is None and self.max is None else super()._describe_range()


class Counted(click.IntRange):
    """A count of at least ``min`` that is also bounded by the resource limit ``limit`` (``schemas.limits``): the
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


_CONTEXT = {"help_option_names": ["-h", "--help"], "max_content_width": 100}


def _apply_limits(ctx: click.Context, param: click.Parameter, pairs: tuple[str, ...]) -> tuple[str, ...]:
    if pairs:
        set_limits(pairs)
    return pairs


#: ``--limit NAME=VALUE`` on both groups: raise (or lower) a resource limit of ``uavplace.schemas.limits.Limits``.
limit_option = click.option(
    "--limit",
    "limit_pairs",
    multiple=True,
    metavar="NAME=VALUE",
    expose_value=False,
    callback=_apply_limits,
    help=f"Raise or lower a resource limit for this command, before the command's name (repeatable): "
    f"{', '.join(f'{k} ({shown(v.default)})' for k, v in Limits.model_fields.items())}. "
    f"The same as the environment variable {LIMITS_ENV}=NAME=VALUE,...; see the README's Security section.",
)


@click.group(
    cls=UavGroup,
    context_settings=_CONTEXT,
    lazy={
        "ingest": "uavplace.ingest.cli:ingest",
        "simulate": "uavplace.simulate.cli:simulate",
        "build": "uavplace.dataset.cli:build",
        "list": "uavplace.dataset.cli:list_",
        "show": "uavplace.dataset.cli:show",
    },
)
@click.version_option(package_name="uavplace", prog_name="uavdata")
@limit_option
def uavdata() -> None:
    """uavplace data pipeline: raw ray-tracer exports -> validated tables -> map bundles.

    \b
    Typical use on a new city:
      uavdata ingest data/raw/cityA/
      uavdata build --city cityA --grid 4m --alt 10
    (the default noise plus interference, {noise:g} dBm, is the level the
    embedded cities and the shipped agents are calibrated at; see the README.)
    """


uavdata.help = uavdata.help.format(noise=EMBEDDED_NOISE_DBM)


@click.group(
    cls=UavGroup,
    context_settings=_CONTEXT,
    lazy={
        "datasets": "uavplace.rl.cli:datasets",
        "baselines": "uavplace.rl.cli:baselines",
        "train": "uavplace.rl.cli:train",
        "ensemble": "uavplace.rl.cli:ensemble",
        "fit-predictor": "uavplace.rl.cli:fit_predictor",
        "train-predictor": "uavplace.rl.cli:train_predictor",
        "report": "uavplace.eval.cli:report",
        "sweep": "uavplace.eval.cli:sweep",
    },
)
@click.version_option(package_name="uavplace", prog_name="uavrl")
@limit_option
def uavrl() -> None:
    """UAV placement agents: the datasets they can use, training, ensembles of runs, sweeps and reports."""


@uavdata.command()
@click.argument("model", required=False, type=click.Choice(sorted(SCHEMA_MODELS)))
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Write one <name>.schema.json per contract into this folder instead of printing.",
)
def schema(model: str | None, out_dir: Path | None) -> None:
    """Print the JSON schema of the contracts (all, or MODEL), so other tools can validate our outputs.

    Table contracts (receivers, transmitters, buildings, building_parts) come
    as the JSON schema of one row, with units and descriptions per column.
    """
    out = stdout()
    schemas = json_schemas()
    if model:
        schemas = {model: schemas[model]}
    if out_dir is None:
        out.print_json(json.dumps(schemas if not model else schemas[model]))
        return
    out_dir.mkdir(parents=True, exist_ok=True)
    for name, s in schemas.items():
        (out_dir / f"{name}.schema.json").write_text(json.dumps(s, indent=2) + "\n", encoding="utf-8")
    out.print(f"wrote {len(schemas)} schema(s) to {out_dir}")


if __name__ == "__main__":  # python -m uavplace.schemas.cli uavdata|uavrl ...: the console scripts without them
    group = {"uavdata": uavdata, "uavrl": uavrl}.get(sys.argv[1] if len(sys.argv) > 1 else "")
    if group is None:
        fail("usage: python -m uavplace.schemas.cli uavdata|uavrl COMMAND ...")
    sys.argv = [sys.argv[1], *sys.argv[2:]]
    group()
