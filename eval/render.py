"""The report's text: table rows, paired differences, groups of seeds, the HTML pages (jinja2) and the Markdown
tables, and the summary of several cities."""

from __future__ import annotations

import base64
import datetime as dt
import functools
import json
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from uavplace.eval.evaluate import PAPER, ReportConfig, paper_key, references
from uavplace.eval.figures import Figure, plot_profiles
from uavplace.eval.findings import (
    HEADLINE_STATS,
    across_findings,
    city_findings,
    difference_cell,
    headline_methods,
    stat_rows,
)
from uavplace.eval.metrics import STATS, aggregate_table, format_stat, pooled, profiles
from uavplace.infra.console import markdown_list, markdown_table
from uavplace.infra.files import atomic_write_bytes, atomic_write_text
from uavplace.schemas import InputError


def difference_rows(differences: pd.DataFrame, t_max: int) -> list[list[str]]:
    """The paired differences as text cells (header first): per method, success and median steps minus each reference."""
    refs = list(dict.fromkeys(differences["against"]))
    header = ["method", *(f"{label} - {ref}" for ref in refs for label in ("success", "median steps"))]
    rows = [header]
    for method, group in differences.groupby("method", sort=False):
        cells = [str(method)]
        for ref in refs:
            for stat in ("success", "median_steps"):
                r = group[(group["against"] == ref) & (group["stat"] == stat)]
                cells.append("-" if r.empty else difference_cell(stat, r.iloc[0]))
        rows.append(cells)
    return rows


def group_rows(
    table: pd.DataFrame, differences: pd.DataFrame, groups: dict[str, list[str]], *, references_too: bool = False
) -> list[list[str]]:
    """``group_tables`` as text cells (header first): each group's runs, success and median steps (mean over its runs,
    interval, the runs' range), then each difference against a reference (the references' own rows only with
    ``references_too``)."""
    refs = list(dict.fromkeys(differences["against"]))
    header = [
        "group",
        "runs",
        "success",
        "median steps",
        *(f"{label} - {ref}" for ref in refs for label in ("success", "median steps")),
    ]
    rows = [header]
    for group in (g for g in groups if references_too or g not in refs):
        cells = [group, ", ".join(groups[group])]
        for stat in ("success", "median_steps"):
            r = table[(table["group"] == group) & (table["stat"] == stat)].iloc[0]
            scale, unit = (100, " %") if stat == "success" else (1, "")
            value = (
                "undefined"
                if np.isnan(r["value"])
                else f"{scale * r['value']:.1f}{unit} [{scale * r['lo']:.1f}, {scale * r['hi']:.1f}]"
            )
            spec = ".1f" if stat == "success" else "g"
            cells.append(f"{value} ({scale * r['run_min']:{spec}}-{scale * r['run_max']:{spec}})")
        for ref in refs:
            for stat in ("success", "median_steps"):
                r = differences[(differences["group"] == group) & (differences["against"] == ref) & (differences["stat"] == stat)]
                cells.append("-" if r.empty else difference_cell(stat, r.iloc[0]))
        rows.append(cells)
    return rows


#: Where the paper columns come from: the paper's table of 1000 test episodes in its unseen city (docs/method.md).
PAPER_SOURCE = (
    "Paper columns: the row of the paper's test-city table named in brackets (proposed: topology + SINR; blind: SINR "
    "only; genie), 1000 episodes in its unseen city, t_max 500 (docs/method.md)"
)


def _figure(fig: Figure | None, number: int, alt: str) -> dict:
    """What the templates' ``figure`` macro draws: the PNG inlined (base64), numbered, with its caption."""
    data = None if fig is None else base64.b64encode(fig.path.read_bytes()).decode("ascii")
    return {"number": number, "alt": alt, "data": data, "caption": None if fig is None else fig.caption}


@functools.cache
def _templates():  # noqa: ANN202 - a jinja2.Environment
    """The report pages' Jinja2 templates (``eval/templates/``), autoescaped: every value is text."""
    import jinja2

    return jinja2.Environment(
        loader=jinja2.PackageLoader("uavplace.eval", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        keep_trailing_newline=True,
    )


def table_rows(table: pd.DataFrame, t_max: int) -> list[list[str]]:
    """The results table as text cells (header first): each statistic with its 95 % interval, then the paper's."""
    header = ["method", *STATS.values(), "paper: success", "paper: median steps"]
    rows = [header]
    for r in table.to_dict("records"):
        cells = [r["method"]]
        cells += [format_stat(s, r[s], r[f"{s}_lo"], r[f"{s}_hi"], t_max) for s in STATS]
        key = paper_key(r["method"])
        cells += ["-" if np.isnan(r["paper_success"]) else f"{100 * r['paper_success']:.0f} % ({PAPER[key]['row']})"]
        cells += ["-" if np.isnan(r["paper_median_steps"]) else f"{r['paper_median_steps']:g} ({PAPER[key]['row']})"]
        rows.append(cells)
    return rows


def split_columns(rows: list[list[str]], first: tuple[str, ...]) -> tuple[list[list[str]], list[list[str]]]:
    """``rows`` (header first, the method in the first column) as two tables that fit a laptop's screen: the columns
    named in ``first``, then the others, each with the method."""
    keep = [0] + [i for i, name in enumerate(rows[0]) if name in first]
    rest = [0] + [i for i in range(1, len(rows[0])) if i not in keep]
    return [[r[i] for i in keep] for r in rows], [[r[i] for i in rest] for r in rows]


#: The headline table's column names (``findings.HEADLINE_STATS``' labels).
HEADLINE_COLUMNS = tuple(STATS[s] for s in HEADLINE_STATS)


_CSS = """body{font-family:system-ui,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:1em 0;font-size:14px;display:block;overflow-x:auto;max-width:100%}
td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}td{white-space:nowrap}.prov td{white-space:normal}
td:first-child,th:first-child{text-align:left}th{background:#f3f3f3}img{max-width:100%}
figure{margin:1.5em 0}figcaption{font-size:14px;color:#333;max-width:1000px}
pre{background:#f7f7f7;padding:8px;overflow-x:auto;font-size:12px}.prov td,.prov th{text-align:left;vertical-align:top}"""


def render_section(
    config: ReportConfig,
    rows: list[list[str]],
    figures: dict[str, Figure | None],
    provenance: dict,
    first_figure: int = 1,
    diff_rows: list[list[str]] | None = None,
    group_rows: list[list[str]] | None = None,
) -> str:
    """One city's results (``templates/section.html.j2``): how the episodes were drawn, the table, the differences,
    then its captioned figures (those in ``figures``: the CDF, the training curves, the trajectories, numbered from
    ``first_figure``)."""
    p = provenance
    penalised = {n: a["config"].get("test_revisit_penalty", 0.0) for n, a in p["agents"].items()}
    penalties = "; ".join(
        f"{n}: less {v:g} per earlier visit of the episode to the cell the move leads to" for n, v in penalised.items() if v
    )
    city = p["test_city"]
    alt = {
        "cdf": f"CDF of steps to P_T in {city}",
        "profile": f"performance profiles in {city}",
        "training": "training curves",
        "trajectories": f"trajectories in {city}",
    }
    shown = [_figure(figures[key], first_figure + i, alt[key]) for i, key in enumerate(k for k in alt if k in figures)]
    headline, detail = split_columns(rows, HEADLINE_COLUMNS)
    maps = cell_sources_text(p["test_bundle_cells"]) if p.get("test_bundle_cells") else None
    drawn = {"episodes": config.episodes, "t_max": config.t_max, "p_t": f"{config.p_t_db:g}", "penalties": penalties}
    drawn |= {"epsilon": f"{config.test_epsilon:g}", "n_boot": config.n_boot, "users": p.get("users", "all")}
    tables = {"rows": headline, "detail_rows": detail, "diff_rows": diff_rows, "group_rows": group_rows, "figures": shown}
    section = _templates().get_template("section.html.j2")
    return section.render(city=p["test_city"], bundle=p["test_bundle"], maps=maps, paper_source=PAPER_SOURCE, **drawn, **tables)


def provenance_rows(provenances: list[dict]) -> list[list[str]]:
    """What made the report, readable: the command, the bundles tested on and every agent (runs, cities, commands)."""
    first = provenances[0]
    rows = [["what", "value"]]
    rows.append(["report command", first["command"]])
    when = first["created_utc"] if len(provenances) == 1 else f"{first['created_utc']} to {provenances[-1]['created_utc']}"
    made = f"{when}, uavplace {first['uavplace_version']}"  # several cities: from the first city's report to the last's
    if "torch" in first:  # reports from before the threads were recorded lack it
        made += f", torch {first['torch']['version']} on {first['torch']['threads']} threads"
    rows.append(["made", made])
    for p in provenances:
        c = p["test_bundle_config"]
        rows.append(
            [
                f"test city {p['test_city']}",
                f"bundle {p['test_bundle']}: grid {c.get('grid_m')} m, altitude "
                f"{c.get('altitude_m')} m, noise + interference {c.get('noise_dbm')} dBm, role {c.get('role') or 'not declared'}",
            ]
        )
        if p.get("test_bundle_cells"):  # reports from before provenance lack it
            rows.append([f"test city {p['test_city']}: its maps", cell_sources_text(p["test_bundle_cells"])])
    for name, a in first["agents"].items():
        trained = ", ".join(f"{k}@{v}" for k, v in (a["trained_on"] or {}).items()) or "unknown"
        selected = ", ".join(f"{k}@{v}" for k, v in (a.get("selected_on") or {}).items()) or "its training cities' held-out users"
        best = a["best_eval"] or {}
        members = a["config"].get("ensemble", 1)
        chosen = (
            f"the mean of {members} runs' best.pt"
            if members > 1
            else f"best.pt from step {best.get('step')}"
            if best
            else "best.pt"
        )
        rows.append(
            [
                f"agent {name}",
                f"{a['folder']}; {a['config']['total_steps']:,} steps; trained on {trained}; selected on {selected}; {chosen}",
            ]
        )
        for i, cmd in enumerate(a["commands"] or ["(not recorded)"]):
            rows.append([f"agent {name}: command {i + 1}", cmd])
    return rows


def cell_sources_text(counts: dict[str, int]) -> str:
    """Where the values of a bundle's maps came from (``Bundle.cell_sources``), in words: the share of the users' cells
    outside buildings of each provenance (docs/simulate.md, "Provenance")."""
    total = max(sum(counts.values()), 1)
    shares = ", ".join(f"{100 * n / total:.1f} % {name}" for name, n in sorted(counts.items(), key=lambda kv: -kv[1]))
    return f"{total:,} user-cells outside buildings: {shares}"


@dataclass
class Top:
    """The top of a report page: what it found in words (``findings``), the headline methods' table (``rows``) and what
    its cells are (``caption``), and across cities the pooled performance profiles."""

    findings: list[str]
    caption: str
    rows: list[list[str]]
    figure: Figure | None = None


def cautioned(findings: list[str], cautions: list[str]) -> list[str]:
    """``findings`` followed by what the command warned of (``evaluate.unlike_training``'s lines), each as a caution."""
    return findings + [f"Caution: {line}." for line in cautions]


def city_top(table: pd.DataFrame, differences: pd.DataFrame, config: ReportConfig, city: str, cautions: list[str]) -> Top:
    """The top of one city's page: ``city_findings``, then ``cautions``, and the headline methods' ``HEADLINE_STATS``."""
    methods = headline_methods(list(table["method"]))
    caption = (
        f"The headline methods in {city} ({config.episodes} episodes; brackets: 95 % paired bootstrap intervals over "
        "users, then episodes; every method and statistic below)."
    )
    rows = stat_rows(table, config.t_max, HEADLINE_STATS, methods)
    return Top(cautioned(city_findings(table, differences, config.t_max), cautions), caption, rows)


def across_top(reports: list[Report], profile_png: Path | None = None) -> Top:
    """The top of a page of several cities: ``across_findings`` and the headline methods over the episodes of every city
    (``aggregate_table``, stratified intervals); with ``profile_png``, the pooled performance profiles drawn there."""
    config = reports[0].config
    by_city = {r.provenance["test_city"]: {m: df for m, df in r.episodes.groupby("method", sort=False)} for r in reports}
    aggregate = aggregate_table(by_city, n_boot=config.n_boot, seed=config.seed)
    cities = {r.provenance["test_city"]: (r.table, r.differences) for r in reports}
    caption = (
        f"The headline methods over the {int(aggregate['episodes'].iloc[0])} episodes of the {len(reports)} cities "
        f"({', '.join(cities)}) at once; brackets: 95 % stratified bootstrap intervals ({config.n_boot} resamples of "
        "each city's users, then their episodes, within each city), as rliable aggregates across tasks."
    )
    figure = None
    if profile_png is not None:
        bands = profiles(pooled(by_city), n_boot=config.n_boot, seed=config.seed, stratified=True)
        figure = plot_profiles(bands, f"the {len(reports)} cities pooled ({', '.join(cities)})", profile_png)
    rows = stat_rows(aggregate, config.t_max, HEADLINE_STATS, headline_methods(list(aggregate["method"])))
    cautions = [line for r in reports for line in r.provenance.get("cautions", [])]  # reports before 0.5 lack them
    return Top(cautioned(across_findings(cities, aggregate, config.t_max), cautions), caption, rows, figure)


def render_page(
    sections: list[str],
    provenances: list[dict],
    top: Top,
    summary: list[list[str]] | None = None,
    training: Figure | None = None,
    caption: str = "",
) -> str:
    """The whole report (``templates/page.html.j2``): its ``top`` (the findings, the headline table; with several
    cities the pooled performance profiles, Figure 1), with several cities a summary table and the training curves
    (Figure 2), then a section per city (``render_section``'s HTML), then the provenance. Self-contained: the style and
    the figures are inlined."""
    import markupsafe

    raw = provenances[0] if len(provenances) == 1 else provenances
    # One city: its report's time. Several: the page's own, when the last city was done (the first city's is earlier).
    made = provenances[0]["created_utc"] if summary is None else dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    return (
        _templates()
        .get_template("page.html.j2")
        .render(
            generator=GENERATOR,
            cities=", ".join(p["test_city"] for p in provenances),
            css=markupsafe.Markup(_CSS),
            made=made,
            command=provenances[0]["command"],
            summary=summary,
            caption=caption,
            top=top,
            top_figure=top.figure and _figure(top.figure, 1, "performance profiles, cities pooled"),
            training=_figure(training, 2, "training curves"),
            sections=[markupsafe.Markup(s) for s in sections],
            provenance=provenance_rows(provenances),
            raw=json.dumps(raw, indent=2),
        )
    )


#: The marker of a report page: ``write_summary_page`` replaces only a page that carries it.
GENERATOR = "uavplace report"


def check_summary_page(out: str | Path) -> None:
    """``InputError`` unless ``out/report.html`` and ``out/summary.csv`` are absent or a report's own (checked before any
    episode is played, so a refusal costs nothing)."""
    page, table = Path(out) / "report.html", Path(out) / "summary.csv"
    if page.is_symlink() or table.is_symlink():
        raise InputError(page, "is a symbolic link: not replaced")
    if page.exists() and f'<meta name="generator" content="{GENERATOR}">' not in page.read_text(
        encoding="utf-8", errors="replace"
    ):
        raise InputError(page, "exists and is not a uavplace report: not replaced (choose another --out)")
    if table.exists() and not page.exists():
        raise InputError(table, "exists without a report page beside it: not replaced (choose another --out)")


def write_summary_page(reports: list[Report], out: str | Path, t_max: int) -> tuple[Path, Top]:
    """``out/report.html``: the findings over every city (``across_top``, the pooled performance profiles in
    ``out/profile.png``), the summary table (method x city), then each city's section, then the provenance;
    ``out/summary.csv`` the same figures as numbers (``summary_frame``). Written to temporary files renamed into place.
    Returns the page and its top (``markdown_tables`` leads with the same)."""
    out = Path(out)
    summary = summary_rows(reports, t_max)
    sections, number = [], 3  # Figure 1: the pooled profiles; 2: the training curves, once above the cities
    for r in reports:
        figures = {k: v for k, v in r.figures.items() if k != "training"}
        sections.append(render_section(r.config, r.rows, figures, r.provenance, first_figure=number, diff_rows=r.diff_rows))
        number += len(figures)
    with tempfile.TemporaryDirectory() as tmp:
        top = across_top(reports, Path(tmp) / "profile.png")
        page = render_page(
            sections, [r.provenance for r in reports], top, summary, reports[0].figures.get("training"), summary_caption(reports)
        )
        atomic_write_bytes(out / "profile.png", top.figure.path.read_bytes())
    for name, text in (("report.html", page), ("summary.csv", summary_frame(reports).to_csv(index=False))):
        atomic_write_text(out / name, text)
    return out / "report.html", top


def markdown_tables(reports: list[Report], t_max: int, top: Top | None = None) -> str:
    """Every table of the reports as Markdown, led by what they found (``top``: by default ``across_top`` with several
    cities, else the city's): then, with several cities, the summary with its caption; per city its headline and
    detail tables and its paired differences (each with what it is)."""
    top = top or (across_top(reports) if len(reports) > 1 else reports[0].top)
    parts = [markdown_list(top.findings), top.caption, markdown_table(top.rows)]
    if len(reports) > 1:
        parts.append(summary_caption(reports))
        parts.append(markdown_table(summary_rows(reports, t_max)))
    for r in reports:
        p = r.provenance
        parts.append(
            f"**{p['test_city']}** ({r.config.episodes} episodes of {p.get('users', '?')} users, bundle "
            f"{p['test_bundle']}, t_max {r.config.t_max}, P_T {r.config.p_t_db:g} dB; 95 % intervals over users, "
            "then episodes)"
        )
        headline, detail = split_columns(r.rows, HEADLINE_COLUMNS)
        parts += [markdown_table(headline), f"The other statistics in {p['test_city']}, and the paper's numbers:"]
        parts.append(markdown_table(detail))
        if len(r.diff_rows) > 1:
            parts.append(f"Paired differences in {p['test_city']}, method minus reference (95 % intervals):")
            parts.append(markdown_table(r.diff_rows))
        if r.group_rows is not None:
            parts.append(
                f"Groups of runs in {p['test_city']}: mean over runs [95 % interval over runs, users, episodes] "
                "(the runs' range), differences paired in users and episodes:"
            )
            parts.append(markdown_table(r.group_rows))
    return "\n\n".join(parts) + "\n"


def summary_caption(reports: list[Report]) -> str:
    """What the summary's cells are: episodes and users per city, what the intervals resample."""
    per_city = ", ".join(
        f"{r.provenance['test_city']}: {r.config.episodes} episodes of {r.provenance.get('users', '?')} users" for r in reports
    )
    n_boot = reports[0].config.n_boot
    return (
        f"Success rate and median steps to P_T (failures count as beyond t_max {reports[0].config.t_max}) in each unseen "
        f"city ({per_city}); brackets: 95 % paired bootstrap intervals ({n_boot} resamples of the users, then of the "
        "episodes of each drawn user). Differences with intervals are in each city's section and in summary.csv."
    )


def summary_rows(reports: list[Report], t_max: int) -> list[list[str]]:
    """Header then one row per method: ``success [interval] / median steps [interval]`` in each report's city (``-``
    where not played)."""
    cities = [r.provenance["test_city"] for r in reports]
    cells: dict[str, dict[str, str]] = {}
    for city, r in zip(cities, reports, strict=True):
        for rec in r.table.to_dict("records"):
            cells.setdefault(rec["method"], {})[city] = " / ".join(
                format_stat(s, rec[s], rec[f"{s}_lo"], rec[f"{s}_hi"], t_max=t_max) for s in ("success", "median_steps")
            )
    return [["method", *(f"{c}: success / median steps" for c in cities)]] + [
        [m, *(c.get(city, "-") for city in cities)] for m, c in cells.items()
    ]


#: The columns of ``summary.csv`` taken from each report's table.
SUMMARY_STATS = ("success", "median_steps", "steps_over_genie", "medians_ratio", "spl")


def summary_frame(reports: list[Report]) -> pd.DataFrame:
    """``summary.csv``: one row per (city, method), numbers only: episodes, users, each of ``SUMMARY_STATS`` with its
    interval (inf: beyond t_max), and the paired differences against the blind paper agent (``minus_blind_paper``) and
    the genie (``minus_genie``) with theirs (NaN where undefined or not played)."""
    rows = []
    for r in reports:
        city = r.provenance["test_city"]
        for rec in r.table.to_dict("records"):
            row: dict[str, object] = {"city": city, "method": rec["method"], "episodes": rec["episodes"], "users": rec["users"]}
            for stat in SUMMARY_STATS:
                row |= {stat: rec[stat], f"{stat}_lo": rec[f"{stat}_lo"], f"{stat}_hi": rec[f"{stat}_hi"]}
            for ref in references(list(r.table["method"])):
                kind = "genie" if ref == "genie" else "blind_paper"
                d = r.differences[(r.differences["method"] == rec["method"]) & (r.differences["against"] == ref)]
                for stat in ("success", "median_steps"):
                    one = d[d["stat"] == stat]
                    values = (np.nan,) * 3 if one.empty else tuple(one.iloc[0][["difference", "lo", "hi"]])
                    names = (f"{stat}_minus_{kind}", f"{stat}_minus_{kind}_lo", f"{stat}_minus_{kind}_hi")
                    row |= dict(zip(names, values, strict=True))
            rows.append(row)
    return pd.DataFrame(rows)


@dataclass
class Report:
    out: Path
    table: pd.DataFrame  # bootstrap_table + paper columns
    differences: pd.DataFrame  # difference_table against the references (the blind paper agent, the genie)
    episodes: pd.DataFrame  # every method's episodes, with a "method" column
    config: ReportConfig
    rows: list[list[str]]  # the table as text (table_rows)
    diff_rows: list[list[str]]  # the differences as text (difference_rows)
    figures: dict[str, Figure | None]  # in the report folder
    provenance: dict  # report.json
    top: Top  # what the page leads with (city_top)
    group_rows: list[list[str]] | None = None  # the groups of seeds as text (group_rows), when --group was given
