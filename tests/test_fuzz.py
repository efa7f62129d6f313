"""The mutation harness (``tests/fuzz.py``) over every parser, each target in a child process under limits.

Every target gets a few dozen examples here (a fixed hypothesis seed, so CI sees the same ones); the long run is
``python -m tests.fuzz --examples 5000``. A child must finish within ``TIMEOUT_S`` and stay under ``MAX_RESIDENT_GIB``
of resident memory (its address space is capped at ``ADDRESS_SPACE_GIB``, so a blow-up fails, not the machine).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest

from tests.conftest import REPO
from tests.fuzz import TARGETS

EXAMPLES = 40
TIMEOUT_S = 240
MAX_RESIDENT_GIB = 2.0
ADDRESS_SPACE_GIB = 8.0


@pytest.mark.parametrize("target", sorted(TARGETS))
def test_mutated_inputs_give_one_clear_error_or_physical_values(target):
    cmd = [sys.executable, "-m", "tests.fuzz", target, "--examples", str(EXAMPLES), "--max-gb", str(ADDRESS_SPACE_GIB)]
    env = os.environ | {"PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}
    res = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-6000:]
    peak = float(re.search(r"peak resident ([0-9.]+) GiB", res.stdout).group(1))
    assert peak < MAX_RESIDENT_GIB, res.stdout
