"""The commands the README, docs/ and experiments/README.md give stay runnable: every `uavdata` and `uavrl` command
names a command that exists and options it has; every script or module they run exists and has the options given."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import click
import pytest

from uavplace.cli import uavdata, uavrl

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", REPO / "experiments" / "README.md", *sorted((REPO / "docs").glob("*.md"))]
GROUPS = {"uavdata": uavdata, "uavrl": uavrl}
#: How a command line starts that this test checks, and what it runs.
STARTS = re.compile(
    r"(?:^|\s|\()(?P<cmd>(?:OMP_NUM_THREADS=\d+ )?(?:uavdata|uavrl|python3? (?:-m tests\.\w+|\S+\.py)|bash \S+\.sh)\b.*)"
)


def commands(text: str) -> list[str]:
    """Command lines in ``text``: each line of a fenced code block (``\\`` continuations joined, `` # `` comments cut)
    and each inline code span, its line breaks made spaces."""
    out = []
    for language, block in re.findall(r"```(\w*)\n(.*?)```", text, re.S):
        if language not in ("", "bash", "sh"):
            continue
        for line in block.replace("\\\n", " ").splitlines():
            out.append(re.split(r"\s#\s", line)[0])
    for span in re.findall(r"`([^`]+)`", re.sub(r"```.*?```", "", text, flags=re.S)):
        out.append(" ".join(span.split()))
    found = []
    for line in out:
        for part in re.split(r"\s(?:&&|\|\||;)\s", line):
            m = STARTS.search(part)
            if m:
                found.append(m.group("cmd").strip())
    return found


def options_of(command: click.Command) -> set[str]:
    return {opt for p in command.params for opt in (*p.opts, *p.secondary_opts)} | {"--help", "-h"}


def check_cli(words: list[str]) -> None:
    """``words`` (``uavdata ...`` or ``uavrl ...``) name a command and only options it or its group has."""
    group: click.Command = GROUPS[words[0]]
    allowed = options_of(group)
    rest = words[1:]
    ctx = click.Context(group)
    while isinstance(group, click.Group):
        name = next((w for w in rest if not w.startswith("-")), None)
        if name is None or not re.fullmatch(r"[a-z][a-z-]*", name):
            return  # the group alone (its --help, --version or --limit)
        sub = group.get_command(ctx, name)
        assert sub is not None, f"{' '.join(words)}: no command {name!r}"
        rest = rest[rest.index(name) + 1 :]
        group = sub
        allowed |= options_of(sub)
    for w in rest:
        if w.startswith("--"):
            opt = w.split("=", 1)[0]
            assert opt in allowed, f"{' '.join(words)}: {opt} is not an option of {group.name}"


def check_script(words: list[str]) -> None:
    """``python SCRIPT ...``, ``python -m tests.X ...`` or ``bash SCRIPT ...``: the file exists and holds every option."""
    if words[1] == "-m":
        path = REPO / (words[2].replace(".", "/") + ".py")
        rest = words[3:]
    else:
        path, rest = REPO / words[1], words[2:]
    assert path.is_file(), f"{' '.join(words)}: no {path.relative_to(REPO)}"
    if "--" in rest:  # what follows a bare -- is `uavrl report`'s (benchmarks/moved.py plays the report with it)
        rest, passed = rest[: rest.index("--")], rest[rest.index("--") + 1 :]
        check_cli(["uavrl", "report", *passed])
    source = path.read_text(encoding="utf-8")
    for local in re.findall(r"^from (\w+) import", source, re.M):  # a module beside it (experiments/common.py)
        if (path.parent / f"{local}.py").is_file():
            source += (path.parent / f"{local}.py").read_text(encoding="utf-8")
    for w in rest:
        if w.startswith("--"):
            opt = w.split("=", 1)[0]
            assert f'"{opt}"' in source or f"'{opt}'" in source or f"{opt} " in source, f"{' '.join(words)}: {opt}?"


def page_commands() -> list[tuple[str, str]]:
    return [(p.relative_to(REPO).as_posix(), c) for p in PAGES for c in commands(p.read_text(encoding="utf-8"))]


@pytest.mark.parametrize(("page", "line"), page_commands())
def test_commands_in_the_docs_run(page: str, line: str) -> None:
    try:
        words = shlex.split(re.sub(r"[\[\]]", " ", line))
    except ValueError:
        words = re.sub(r"[\[\]]", " ", line).split()
    words = [w for w in words if not re.fullmatch(r"OMP_NUM_THREADS=\d+|\.\.\.|\|", w)]
    if words[0] in GROUPS:
        check_cli(words)
    else:
        check_script(words)


def test_the_pages_hold_commands() -> None:
    """The extraction finds the README's main job and the pages' commands (so the test above cannot pass empty)."""
    found = page_commands()
    assert len(found) > 100
    assert any(c.startswith("uavdata build --grid 4m --alt 10") for _, c in found)
    assert commands("run `uavrl report --bogus` and\n```bash\nuavdata build \\\n  --grid 4m # a comment\n```") == [
        "uavdata build    --grid 4m",
        "uavrl report --bogus",
    ]
    with pytest.raises(AssertionError, match="--bogus"):
        check_cli(["uavrl", "report", "--bogus"])
    with pytest.raises(AssertionError, match="no command"):
        check_cli(["uavrl", "reprot"])


def test_the_docs_and_the_readme_are_undated():
    """docs/ and the README say what is true now: no page dates a measurement or names a commit (the history lives in
    experiments/log/ and the CHANGELOG), and no page of docs/ runs over 400 lines (a guide, not a log)."""
    dated = re.compile(r"\b20\d\d-[01]\d-[0-3]\d\b")
    commit = re.compile(r"\bcommits? [0-9a-f]{7,40}\b|^\| [0-9a-f]{7,40} \|")
    for page in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]:
        text = page.read_text(encoding="utf-8").splitlines()
        lines = [n for n, line in enumerate(text, 1) if dated.search(line)]
        assert not lines, f"{page.relative_to(REPO)}:{lines[0]} is dated"
        lines = [n for n, line in enumerate(text, 1) if commit.search(line)]
        assert not lines, f"{page.relative_to(REPO)}:{lines[0]} names a commit"
        if page.parent.name == "docs":
            assert len(text) <= 400, f"{page.relative_to(REPO)} holds {len(text)} lines, more than 400"


def test_the_readmes_numbers_about_the_code_are_the_codes():
    """What the README states about the code comes from it: the paper agents' training steps (the shipped run.json,
    beside the preset's own), each preset's steps in `uavrl train --help` (the presets' total_steps), and the budget
    of the training maps (the test in tests/test_trainmaps.py). No count of tests is stated (it changes with
    every test)."""
    import json

    from uavplace.rl.agent.config import preset_config

    readme = (REPO / "README.md").read_text(encoding="utf-8")
    shipped = {json.loads((REPO / "data" / "agents" / a / "run.json").read_text())["config"]["total_steps"]
               for a in ("proposed", "blind")}  # fmt: skip
    assert shipped == {300_000} and "trained for\n  300 k steps rather than the preset's 7 M" in readme
    assert preset_config("paper").total_steps == 7_000_000
    train_help = uavrl.commands["train"] if "train" in uavrl.commands else uavrl.get_command(click.Context(uavrl), "train")
    text = " ".join(" ".join(p.help.split()) for p in train_help.params if p.name == "preset")
    for preset, words in (("best", "300 k steps"), ("paper", "about 7 M steps"), ("fast", "40 k")):
        steps = preset_config(preset).total_steps
        assert words in text and steps == {"300 k steps": 300_000, "about 7 M steps": 7_000_000, "40 k": 40_000}[words]
    assert not re.search(r"\b\d{3} tests\b", readme), "the README states a count of tests: it changes with every test"


def test_the_citation_file_cites_the_project_and_the_paper():
    """CITATION.cff is valid YAML in the Citation File Format's shape, at the package's version, and cites the paper
    docs/method.md summarises."""
    yaml = pytest.importorskip("yaml", reason="PyYAML missing")
    from importlib.metadata import version

    doc = yaml.safe_load((REPO / "CITATION.cff").read_text(encoding="utf-8"))
    assert doc["cff-version"] == "1.2.0" and doc["type"] == "software" and doc["authors"]
    assert doc["version"] == version("uavplace") and doc["license"] == "MIT"
    (paper,) = doc["references"]
    assert paper["year"] == 2019 and [a["family-names"] for a in paper["authors"]] == ["Krijestorac", "Hanna", "Cabric"]
    assert paper["title"] in " ".join((REPO / "docs" / "method.md").read_text(encoding="utf-8").split())


def test_the_readme_is_short_and_the_changelog_one_line_a_change():
    """The README reads in five minutes (at most 300 lines); the CHANGELOG's releases hold only the headings Added,
    Changed and Fixed, each change one line of at most 160 characters (its numbers linked, not restated)."""
    assert len((REPO / "README.md").read_text(encoding="utf-8").splitlines()) <= 300
    lines = (REPO / "CHANGELOG.md").read_text(encoding="utf-8").splitlines()
    first = next(n for n, line in enumerate(lines) if line.startswith("## "))
    for n, line in enumerate(lines[first:], first + 1):
        if line.startswith("### "):
            assert line in ("### Added", "### Changed", "### Fixed"), f"CHANGELOG.md:{n}: {line}"
        elif line.strip() and not line.startswith("## "):
            assert line.startswith("- ") and len(line) <= 160, f"CHANGELOG.md:{n} is not one line of a change"


def test_the_main_job_benchmark_times_the_readmes_first_command():
    """``benchmarks/main_job.py`` reads the README's first command past the comments that label it: ingest, build and
    the report, the install left out."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("main_job", REPO / "benchmarks" / "main_job.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    commands = module.main_job(REPO / "README.md")
    assert [c.split()[:2] for c in commands] == [["uavdata", "ingest"], ["uavdata", "build"], ["uavrl", "report"]]
