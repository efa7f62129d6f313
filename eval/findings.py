"""What a placement report found, in a short table and a few sentences made from its numbers: the top of its pages.

The headline methods are the map searcher, the shipped learner (``(best)``), the paper's agents and the genie (the
bound); the headline statistics are the success rate, the paper's ratio of medians, SPL and the interquartile means.
A sentence says which method leads, by how much against the next (a paired difference, where the report has it), and
whether the map matters to the leader (the cost of blanking its buildings). Every number comes from the report's own
tables; nothing here is typed by hand.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from uavplace.eval.evaluate import NO_BUILDINGS, WITH_BUILDINGS
from uavplace.rl.tasks.placement.searcher import SEARCHER
from uavplace.rl.world.stats import STATS, format_stat

#: The statistics of a report's headline table (its first): the others are in the detail table.
HEADLINE_STATS = ("success", "medians_ratio", "spl", "iqm_over_genie", "iqm_spl")


def headline_methods(methods: list[str]) -> list[str]:
    """The methods at the top of a page: the map searcher, the shipped learners ``(best)``, the paper's agents and the
    genie, in the report's order (no ablation: what blanking costs is a sentence)."""

    def shown(m: str) -> bool:
        return m in (SEARCHER, "genie") or m.endswith("(best)") or m.endswith("(paper)")

    return [m for m in methods if shown(m) and not m.endswith(NO_BUILDINGS)]


def stat_rows(table: pd.DataFrame, t_max: int, stats: tuple[str, ...], methods: list[str] | None = None) -> list[list[str]]:
    """Text cells (header first) of ``stats`` with their intervals, one row per method of ``table`` (``methods``: those
    only, in their order)."""
    by_name = {r["method"]: r for r in table.to_dict("records")}
    rows = [["method", *(STATS[s] for s in stats)]]
    for name in methods if methods is not None else list(by_name):
        r = by_name[name]
        rows.append([name, *(format_stat(s, r[s], r[f"{s}_lo"], r[f"{s}_hi"], t_max) for s in stats)])
    return rows


def ranking(table: pd.DataFrame, bound: str = "genie") -> list[str]:
    """The methods other than the ``bound`` (the genie; the fleet's oracle) and the ablations, best first: by success,
    then the paper's ratio (fewer steps), then SPL."""
    rows = [r for r in table.to_dict("records") if r["method"] != bound and not r["method"].endswith(NO_BUILDINGS)]
    rows.sort(key=lambda r: (-r["success"], r["medians_ratio"], -r["spl"]))
    return [r["method"] for r in rows]


def difference_cell(stat: str, r: pd.Series | dict) -> str:
    """A paired difference with its interval, in words: points of success, or steps."""
    if np.isnan(r["difference"]):
        return f"undefined ({100 * r['undefined_share']:.0f} % of resamples: a median beyond t_max)"
    if stat == "success":
        return f"{100 * r['difference']:+.1f} points [{100 * r['lo']:+.1f}, {100 * r['hi']:+.1f}]"
    values = (r["difference"], r["lo"], r["hi"])
    if all(float(v).is_integer() for v in values):  # one run's medians: whole steps
        return f"{r['difference']:+g} [{r['lo']:+g}, {r['hi']:+g}]"
    return f"{r['difference']:+.1f} [{r['lo']:+.1f}, {r['hi']:+.1f}]"  # a mean over runs


def paired(differences: pd.DataFrame, method: str, against: str) -> dict[str, dict] | None:
    """``{stat: row}`` of the paired difference ``method - against`` (the reverse of a difference the report holds
    the other way round, its interval mirrored); None when the report holds neither."""
    if differences.empty:
        return None
    for a, b, sign in ((method, against, 1.0), (against, method, -1.0)):
        rows = differences[(differences["method"] == a) & (differences["against"] == b)]
        if not rows.empty:
            out = {}
            for r in rows.to_dict("records"):
                lo, hi = sorted((sign * r["lo"] + 0.0, sign * r["hi"] + 0.0))  # + 0.0: no "-0" of a mirrored 0
                out[r["stat"]] = r | {"difference": sign * r["difference"] + 0.0, "lo": lo, "hi": hi}
            return out
    return None


def _changes(d: dict[str, dict]) -> str:
    """A paired difference of success and of median steps, in words."""
    success, steps = (difference_cell(s, d[s]) for s in ("success", "median_steps"))
    return f"{success} of success and {steps} median steps"


def _matters(d: dict[str, dict]) -> str:
    """Whether a cost of blanking the map is told apart from chance (an interval of success or steps that excludes 0)."""
    tells = [r for r in d.values() if not np.isnan(r["difference"]) and (r["lo"] > 0 or r["hi"] < 0)]
    return "the map matters" if tells else "no cost told apart from chance: the map does not measurably matter here"


def city_findings(
    table: pd.DataFrame, differences: pd.DataFrame, t_max: int, bound: str = "genie", succeed: str = "reach P_T"
) -> list[str]:
    """One sentence per finding of one city's report: which method leads, by how much against the next, and what
    blanking the buildings costs the leader. ``bound``: the method every step count is divided by (the fleet's
    oracle); ``succeed``: what a successful episode does."""
    order = ranking(table, bound)
    if not order:
        return []
    r = table.set_index("method").loc[order[0]]
    lead = order[0]
    out = [
        f"{lead} leads: {format_stat('success', r['success'])} of the episodes {succeed}, at "
        f"{format_stat('medians_ratio', r['medians_ratio'], t_max=t_max)} x the {bound}'s median steps (SPL "
        f"{format_stat('spl', r['spl'])}, IQM of steps / {bound} {format_stat('iqm_over_genie', r['iqm_over_genie'])})."
    ]
    if len(order) > 1 and (d := paired(differences, lead, order[1])) is not None:
        out.append(f"Against the next, {order[1]}, paired: {_changes(d)}.")
    if (d := paired(differences, lead + NO_BUILDINGS, WITH_BUILDINGS)) is not None:
        out.append(f"Shown no building, {lead} changes by {_changes(d)}: {_matters(d)}.")
    return out


def across_findings(cities: dict[str, tuple[pd.DataFrame, pd.DataFrame]], aggregate: pd.DataFrame, t_max: int) -> list[str]:
    """The findings of a report of several cities (``{city: (table, differences)}``) and their ``aggregate_table``:
    who leads where, the leader's aggregate, by how much against the next and what the map costs it, city by city."""
    leads = {city: ranking(t)[0] for city, (t, _) in cities.items() if ranking(t)}
    if not leads:
        return []
    order = ranking(aggregate)
    lead = order[0] if order else next(iter(leads.values()))
    where = [c for c, m in leads.items() if m == lead]
    span = "every city" if len(where) == len(leads) else f"{len(where)} of {len(leads)} cities"
    others = "".join(f"; {m} in {c}" for c, m in leads.items() if m != lead)
    out = [f"{lead} leads in {span} ({', '.join(where)}){others}."]
    if lead in set(aggregate["method"]):
        r = aggregate.set_index("method").loc[lead]
        stats = ", ".join(f"{STATS[s]} {format_stat(s, r[s], r[f'{s}_lo'], r[f'{s}_hi'], t_max)}" for s in HEADLINE_STATS)
        out.append(f"Over the episodes of all {int(r['cities'])} cities (intervals resample within each city), {lead}: {stats}.")
    runner = order[1] if len(order) > 1 else None
    per_city = [(c, paired(d, lead, runner)) for c, (_, d) in cities.items()] if runner else []
    if per_city and all(d is not None for _, d in per_city):
        out.append(f"Against the next, {runner}, paired: " + "; ".join(f"{_changes(d)} in {c}" for c, d in per_city) + ".")
    blanked = [(c, paired(d, lead + NO_BUILDINGS, WITH_BUILDINGS)) for c, (_, d) in cities.items()]
    if blanked and all(d is not None for _, d in blanked):
        costs = "; ".join(f"{_changes(d)} in {c} ({_matters(d)})" for c, d in blanked)
        out.append(f"Shown no building, {lead} changes by {costs}.")
    return out
