"""The ``uavdata`` and ``uavrl`` command groups: the one module that knows every stage.

Each stage keeps its commands in its own package (``ingest/cli.py``, ``simulate/cli.py``, ``dataset/cli.py``,
``rl/cli.py`` and ``rl/predictor/cli.py``, ``eval/cli.py``). The groups here name them by import path and load a
command's module only when that command (or ``--help``) needs it, so that no stage imports another for its command
line, and ``uavdata ingest`` never loads the ray tracer. Every failure is one ``error: ...`` line and exit status 2 (``UavGroup``).
"""

from __future__ import annotations

import difflib
import importlib
import json
import os
import sys
from pathlib import Path

import click

from uavplace.infra.console import fail, path_option, stdout
from uavplace.infra.files import describe_os_error
from uavplace.infra.limits import ENV as LIMITS_ENV
from uavplace.infra.limits import set_limits
from uavplace.schemas import InputError
from uavplace.schemas.bundle import EMBEDDED_NOISE_DBM
from uavplace.schemas.export import SCHEMA_MODELS, json_schemas


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

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The commands with the whole first sentence of each one's help, wrapped, never cut with "..."."""
        rows = []
        for name in self.list_commands(ctx):
            cmd = self.get_command(ctx, name)
            if cmd is not None and not cmd.hidden:
                rows.append((name, cmd.get_short_help_str(limit=10_000)))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*super().list_commands(ctx), *self.lazy})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in self.lazy and cmd_name not in self.commands:
            module, _, attribute = self.lazy[cmd_name].partition(":")
            self.add_command(getattr(importlib.import_module(module), attribute), cmd_name)
        return super().get_command(ctx, cmd_name)

    def resolve_command(self, ctx: click.Context, args: list[str]) -> tuple:
        """As click's, but a mistyped command is answered with the nearest commands, lazy ones included (click offers
        only those already loaded)."""
        name = args[0]
        if not name.startswith("-") and not ctx.resilient_parsing and self.get_command(ctx, name) is None:
            near = difflib.get_close_matches(name, self.list_commands(ctx), n=3)
            hint = f" Did you mean {' or '.join(repr(n) for n in near)}?" if near else ""
            raise click.UsageError(f"No such command {name!r}.{hint}", ctx)
        return super().resolve_command(ctx, args)

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


_CONTEXT = {"help_option_names": ["-h", "--help"], "max_content_width": 100}


def _apply_limits(ctx: click.Context, param: click.Parameter, pairs: tuple[str, ...]) -> tuple[str, ...]:
    if pairs:
        set_limits(pairs)
    return pairs


#: ``--limit NAME=VALUE`` on both groups: raise (or lower) a resource limit of ``uavplace.infra.limits.Limits``.
limit_option = click.option(
    "--limit",
    "limit_pairs",
    multiple=True,
    metavar="NAME=VALUE",
    expose_value=False,
    callback=_apply_limits,
    help=f"Raise or lower a resource limit for this command, before the command's name (repeatable; the same as "
    f"{LIMITS_ENV}=NAME=VALUE,...). Every limit, its default and what it bounds: docs/security.md, 'Resource "
    "limits'; an error over one names it and this option.",
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
        "pack": "uavplace.dataset.cli:pack",
        "export": "uavplace.dataset.cli:export",
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
        "fit-predictor": "uavplace.rl.predictor.cli:fit_predictor",
        "train-predictor": "uavplace.rl.predictor.cli:train_predictor",
        "calibrate-predictor": "uavplace.rl.predictor.cli:calibrate_predictor",
        "trace-predictor": "uavplace.rl.predictor.cli:trace_predictor",
        "report": "uavplace.eval.cli:report",
        "sweep": "uavplace.eval.compare_cli:sweep",
        "levers": "uavplace.eval.compare_cli:levers",
        "robustness": "uavplace.eval.robustness:robustness",
        "peer": "uavplace.eval.compare_cli:peer",
    },
)
@click.version_option(package_name="uavplace", prog_name="uavrl")
@limit_option
def uavrl() -> None:
    """UAV placement agents: the datasets they can use, training, ensembles of runs, sweeps and reports.

    \b
    Typical use, after `uavdata ingest` and `uavdata build`:
      uavrl report                              the shipped agents, the map searcher and the baselines in the test cities
      uavrl report --dataset cityA              ... in a city of yours (reports/)
      uavrl train --dataset corpus --dataset oldtown --name mine
      uavrl report --dataset cityA --run runs/mine
      uavrl report --task tracking              a user who moves (cities with routes)
    """


@uavdata.command()
@click.argument("model", required=False, type=click.Choice(sorted(SCHEMA_MODELS)))
@path_option(
    "--out",
    "out_dir",
    folder=True,
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


def main() -> None:
    """``python -m uavplace.cli uavdata|uavrl ...``: the console scripts without them."""
    group = {"uavdata": uavdata, "uavrl": uavrl}.get(sys.argv[1] if len(sys.argv) > 1 else "")
    if group is None:
        fail("usage: python -m uavplace.cli uavdata|uavrl COMMAND ...")
    sys.argv = [sys.argv[1], *sys.argv[2:]]
    group()
