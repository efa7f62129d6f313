"""uavplace installs under one import namespace, beside distributions that took its folders' names on PyPI."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tests.conftest import REPO

STAGES = ("schemas", "infra", "ingest", "simulate", "dataset", "rl", "eval", "cli")


def _python(code: str, cwd: Path) -> str:
    """Run ``code`` in a fresh interpreter outside the repository (its top-level folders are then not on sys.path)."""
    proc = subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc.stdout


def test_beside_the_dataset_distribution(tmp_path):
    """``dataset`` 2.0.0 (a database toolkit; the test extra installs it) and ``uavplace.dataset`` import together,
    each is itself, and ``uavdata --help`` still works."""
    out = _python(
        "import importlib.metadata as m, dataset, uavplace.dataset.bundle as ours\n"
        "db = dataset.connect('sqlite:///:memory:')\n"  # the toolkit's own API: the real distribution, not our folder
        "db['t'].insert({'x': 1})\n"
        "print(m.version('dataset'), db['t'].count(), dataset.__file__, ours.__file__)\n",
        tmp_path,
    )
    version, rows, theirs, ours = out.split()
    assert version == "2.0.0" and rows == "1"
    assert not Path(theirs).is_relative_to(REPO / "dataset") and Path(ours) == REPO / "dataset" / "bundle.py"
    proc = subprocess.run([str(Path(sys.executable).parent / "uavdata"), "--help"], cwd=tmp_path, capture_output=True, text=True)
    assert proc.returncode == 0 and "ingest" in proc.stdout and "simulate" in proc.stdout


def test_no_stage_is_a_top_level_module(tmp_path):
    """Outside the repository, no stage folder is importable by its bare name (only other distributions' modules are)."""
    out = _python(
        "import importlib.util, json\n"
        f"print(json.dumps({{n: getattr(importlib.util.find_spec(n), 'origin', None) for n in {STAGES!r}}}))\n",
        tmp_path,
    )
    import json

    for name, origin in json.loads(out).items():
        assert origin is None or not Path(origin).is_relative_to(REPO / name), (name, origin)  # e.g. PyPI's dataset


def test_a_command_loads_only_its_own_stage(tmp_path):
    """``uavdata ingest --help`` loads the ingest stage's command, not the ray tracer, the bundles or the agents."""
    out = _python(
        "import sys\n"
        "from uavplace.cli import uavdata\n"
        "try:\n"
        "    uavdata.main(['ingest', '--help'], standalone_mode=False)\n"
        "finally:\n"
        "    print(' '.join(sorted(m for m in sys.modules if m.startswith('uavplace.') or m in ('torch', 'ray'))))\n",
        tmp_path,
    )
    loaded = set(out.splitlines()[-1].split())
    assert "uavplace.ingest.cli" in loaded
    assert not loaded & {"uavplace.simulate.cli", "uavplace.dataset.cli", "uavplace.rl.cli", "uavplace.eval.cli", "torch", "ray"}


#: The package's layers, lowest first: a module imports its own layer's and lower ones' only.
LAYERS = ("schemas", "infra", "ingest", "simulate", "dataset", "rl", "eval", "cli")


def _imports() -> dict[str, set[str]]:
    """Every package module and the ``uavplace`` modules it imports (at the top or inside functions)."""
    import ast

    graph: dict[str, set[str]] = {}
    for layer in LAYERS:
        for path in sorted((REPO / layer).rglob("*.py")):
            parts = path.relative_to(REPO).with_suffix("").parts
            name = "uavplace." + ".".join(p for p in parts if p != "__init__")
            found = set()
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("uavplace."):
                    found.add(node.module)
                elif isinstance(node, ast.Import):
                    found |= {a.name for a in node.names if a.name.startswith("uavplace.")}
            graph[name] = found
    return graph


def test_imports_flow_one_way_without_a_cycle():
    """schemas <- infra <- ingest <- simulate <- dataset <- rl <- eval <- cli: no module imports a higher layer (the
    command groups of ``uavplace.cli`` load the stages' commands by name, never by import), and the modules' imports
    form no cycle."""
    graph = _imports()
    assert len(graph) > 60
    upward = [(m, i) for m, found in graph.items() for i in found
              if LAYERS.index(i.split(".")[1]) > LAYERS.index(m.split(".")[1])]  # fmt: skip
    assert not upward
    state: dict[str, int] = {}

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for i in sorted(graph.get(m, ())):
            if i in graph and i != m:
                assert state.get(i) != 1, " -> ".join([*path, m, i])
                if i not in state:
                    visit(i, [*path, m])
        state[m] = 2

    for m in graph:
        if m not in state:
            visit(m, [])


def test_p_t_and_the_target_rule_have_one_home_each():
    """P_T's default (5 dB) is written in schemas/constants.py only, every model and command reading it there; the
    rule "a cell reaches P_T" (an SINR at or above P_T) is ``schemas.constants.reaches_target`` only."""
    import re

    default = re.compile(r"(p_t_db|p-t-db)\W.*default=5\.0|p_t_db: float = 5\.0")
    rule = re.compile(r"(>=|<)\s*[\w.]*p_t(_db)?\b")
    found = []
    for stage in STAGES:
        for path in sorted((REPO / stage).rglob("*.py")):
            if path.name == "constants.py" and stage == "schemas":
                continue
            text = path.read_text(encoding="utf-8")
            for n, line in enumerate(text.splitlines(), 1):
                if default.search(line) or (rule.search(line) and not line.lstrip().startswith(("#", '"', "``"))):
                    found.append(f"{path.relative_to(REPO)}:{n}: {line.strip()}")
    assert not found, "\n".join(found)
    from uavplace.rl.tasks.placement.config import EnvConfig
    from uavplace.schemas.constants import P_T_DB, reaches_target

    assert EnvConfig().p_t_db == P_T_DB == 5.0
    assert reaches_target([4.99, 5.0, 6.0], 5.0, dead=[False, False, True]).tolist() == [False, True, False]


def test_the_env_and_the_belief_import_no_policy():
    """The placement env, its maps and views, the belief (``rl.belief``: the searcher's predicted maps, their cache
    and arithmetic) and the settings import no policy: the env's belief channel reads ``rl.belief``, never the
    searcher; the policies sit above them."""
    graph = _imports()
    below = ["uavplace.rl." + m for m in ("belief", "config", "randomness", "predictor")]
    below += ["uavplace.rl.world." + m for m in ("settings", "maps", "rows", "stats", "view")]
    below += ["uavplace.rl.tasks.placement." + m for m in ("config", "env", "gym")]
    policies = {f"uavplace.rl.tasks.{t}.{m}" for t in ("placement", "tracking", "fleet") for m in ("searcher", "policies")}
    found = {m: sorted(i for i in graph[m] if i in policies or i.startswith("uavplace.rl.agent")) for m in below}
    assert not any(found.values()), found


#: A task folder's files, lowest first: a file imports the task's lower files only (``rl/tasks/__init__.py``).
TASK_FILES = ("config", "maps", "env", "policies", "searcher", "rollout", "learner", "gym", "zoo")


def test_the_task_folders_have_the_same_files_layered():
    """Every folder of ``rl/tasks/`` holds the task files (``TASK_FILES``; ``maps`` and ``zoo`` where the task has them) and nothing else, and a
    file imports only the files of its task below it (the package's ``__init__`` re-exports them all)."""
    graph = _imports()
    tasks = [p for p in sorted((REPO / "rl" / "tasks").iterdir()) if p.is_dir() and p.name != "__pycache__"]
    assert tasks
    for folder in tasks:
        files = {p.stem for p in folder.glob("*.py")} - {"__init__"}
        # placement's map set is the engine's (rl/world/maps.py); tracking and fleet lay theirs on it
        assert set(TASK_FILES) - {"zoo", "maps"} <= files <= set(TASK_FILES), folder
        prefix = f"uavplace.rl.tasks.{folder.name}."
        for name in files:
            mine = {i.removeprefix(prefix) for i in graph[prefix + name] if i.startswith(prefix)}
            above = {i for i in mine if TASK_FILES.index(i) >= TASK_FILES.index(name)}
            assert not above, f"{folder.name}/{name}.py imports {sorted(above)}"


#: The layers inside ``rl/``, lowest first: a module imports its own layer's and lower ones' only. ``rl.config``,
#: ``rl.randomness`` and ``rl.predictor`` stand on nothing of ``rl/`` but each other.
RL_LAYERS = (
    ("config", "randomness", "predictor"),
    ("world",),
    ("belief",),
    ("tasks",),
    ("agent", "cli"),
)


def _rl_layer(module: str) -> int:
    top = module.split(".")[2] if module.count(".") >= 2 else ""
    return next(n for n, names in enumerate(RL_LAYERS) if top in names)


def test_the_layers_of_rl_the_world_below_the_tasks_below_the_learner():
    """Inside ``rl/``: the engine (``rl/world``: map set, episode rows, statistics, view, observation settings) imports
    no task, belief, learner or command; the belief stands on the world; a task imports no learner, no Gymnasium face
    and no command (the trainer calls the tasks, never the other way); and the engine's modules are there."""
    graph = _imports()
    rl = {m: found for m, found in graph.items() if m.startswith("uavplace.rl.") and m.count(".") >= 2}
    assert {"uavplace.rl.world." + m for m in ("settings", "maps", "rows", "stats", "view")} <= set(rl)
    up = sorted(
        (m, i)
        for m, found in rl.items()
        for i in found
        if i.startswith("uavplace.rl.") and i.count(".") >= 2 and _rl_layer(i) > _rl_layer(m)
    )
    assert not up, up


def test_a_task_is_named_by_its_folder_the_registry_and_its_report_alone():
    """Beyond placement (the task the others build on), no module of the package imports a task but its own folder
    and its report's folder (``eval/reports/<task>/``); the registry lists the folders, and
    each folder's ``__init__`` declares the task's entry (``rl.tasks.entry.Task``)."""
    from uavplace.rl.tasks.entry import Task
    from uavplace.rl.tasks.registry import FOLDERS, TASKS

    graph = _imports()
    assert list(TASKS) == list(FOLDERS) and all(isinstance(t, Task) for t in TASKS.values())
    for task in FOLDERS[1:]:
        folder = f"uavplace.rl.tasks.{task}"
        users = sorted(m for m, found in graph.items() if not m.startswith(folder) and any(i.startswith(folder) for i in found))
        assert all(m.startswith(f"uavplace.eval.reports.{task}") for m in users), (task, users)


def test_the_wheel_lists_every_package_folder():
    """Every folder of a stage that holds an ``__init__.py`` is a package of pyproject.toml's list (an editable install
    finds a missing one anyway; a wheel would leave it out), and the list names no folder that is not there."""
    import tomllib

    setuptools = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]
    folders = {
        "uavplace." + ".".join(p.parent.relative_to(REPO).parts)
        for stage in STAGES
        for p in (REPO / stage).rglob("__init__.py")
        if "__pycache__" not in p.parts
    }
    assert set(setuptools["packages"]) == folders
    assert set(setuptools["package-dir"]) == {f"uavplace.{stage}" for stage in STAGES}
