"""The test suite on a machine shared with another job: tests alone and beside a 2-thread CPU job, at torch's thread
settings, each test's wall and CPU seconds (its process and the commands it ran) and the ratios loaded / alone.

    python benchmarks/shared_machine.py                      # the training tests (about 20 minutes on 2 cores)
    python benchmarks/shared_machine.py tests/test_env.py    # any pytest selection

The settings compared: ``threads 1`` is the suite as it runs (tests/conftest.py sets OMP_NUM_THREADS=1 unless it is
set); ``threads 2`` sets OMP_NUM_THREADS=2, torch's threads on both cores as the trainer takes them outside the tests.
The job beside is a process multiplying matrices on 2 torch threads for as long as the tests run. The targets
(issue 91): beside such a job the selection takes at most 2.5 x its wall time alone, and no test more than 1.5 x its
CPU seconds alone.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: The tests that train (the slowest of the suite, where torch's threads spin when they cannot have both cores).
DEFAULT_TESTS = (
    "tests/test_agent.py::test_resume_continues_exactly",
    "tests/test_agent.py::test_short_training_run_learns",
    "tests/test_agent.py::test_uavrl_train_cli",
)
BURNER = "import torch\ntorch.set_num_threads(2)\na = torch.randn(600, 600)\nwhile True:\n    a = torch.tanh(a @ a)\n"
#: A loaded run is stopped past this many times its wall time alone (plus a minute): it has failed the target anyway.
LIMIT_X = 5
#: A pytest plugin (written beside the run) that records each test's wall and CPU seconds, its children's included.
PLUGIN = """
import json, os, resource, time
import pytest

TIMES = {}


def _cpu():
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    wall, cpu = time.perf_counter(), _cpu()
    yield
    TIMES[item.nodeid] = (time.perf_counter() - wall, _cpu() - cpu)


def pytest_sessionfinish(session):
    with open(os.environ["SHARED_MACHINE_TIMES"], "w") as f:
        json.dump(TIMES, f)
"""


def run(
    tests: list[str], threads: int, loaded: bool, folder: Path, limit: float | None = None
) -> dict[str, tuple[float, float]] | None:
    """Each test's (wall, CPU) seconds of one pytest run at ``threads`` torch threads, beside the burner if ``loaded``;
    None when it ran past ``limit`` seconds (stopped there)."""
    times = folder / f"times-{threads}-{int(loaded)}.json"
    env = os.environ | {
        "OMP_NUM_THREADS": str(threads),
        "PYTHONPATH": f"{folder}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
        "SHARED_MACHINE_TIMES": str(times),
    }
    burner = subprocess.Popen([sys.executable, "-c", BURNER]) if loaded else None
    try:
        if burner is not None:
            time.sleep(2.0)  # the job beside is at full speed before the tests start
        cmd = [sys.executable, "-m", "pytest", "-q", "-p", "shared_machine_plugin", "-p", "no:cacheprovider", *tests]
        try:
            subprocess.run(cmd, cwd=REPO, env=env, check=True, stdout=subprocess.DEVNULL, timeout=limit)
        except subprocess.TimeoutExpired:
            return None
    finally:
        if burner is not None:
            burner.kill()
            burner.wait()
    return {k: tuple(v) for k, v in json.loads(times.read_text()).items()}


def main() -> None:
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # a kill stops the job beside too (run's finally)
    tests = sys.argv[1:] or list(DEFAULT_TESTS)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "shared_machine_plugin.py").write_text(PLUGIN)
        for threads in (1, 2):
            alone = run(tests, threads, False, folder)
            alone_wall, alone_cpu = (sum(v[i] for v in alone.values()) for i in (0, 1))
            print(f"threads {threads}: alone {alone_wall:.1f} s wall {alone_cpu:.1f} s CPU", flush=True)
            limit = LIMIT_X * alone_wall + 60
            loaded = run(tests, threads, True, folder, limit)
            if loaded is None:
                print(f"  beside a 2-thread job: stopped after {limit:.0f} s wall, over {LIMIT_X} x alone", flush=True)
                continue
            wall, cpu = (sum(v[i] for v in loaded.values()) for i in (0, 1))
            print(f"  beside a 2-thread job: {wall:.1f} s wall {cpu:.1f} s CPU: wall x {wall / alone_wall:.2f}", flush=True)
            worst = max(alone, key=lambda k: loaded[k][1] / max(alone[k][1], 1e-3))
            print(f"  the test whose CPU grew most: x {loaded[worst][1] / max(alone[worst][1], 1e-3):.2f} {worst} "
                  f"({alone[worst][1]:.1f} s alone, {loaded[worst][1]:.1f} s beside)", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
