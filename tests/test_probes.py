"""The probe suite (``tests/probes.py``) as test cases, one a probe: hostile inputs through the real command lines,
each in a child process, every outcome classified. Opt-in, ``pytest --probes`` (about an hour on 2 cores); a
probe fails when its command errs internally, hangs, blows up, exits 0 on a result that fails its check, loses a
race's result, or refuses in anything but one clear error line. Without ``--probes`` the probes are not even built."""

from __future__ import annotations

from pathlib import Path

import pytest

pytestmark = pytest.mark.probes


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    if "probe_case" not in metafunc.fixturenames:
        return
    if not metafunc.config.getoption("--probes"):
        skip = pytest.mark.skip(reason="the probe suite: run it with pytest --probes (about an hour on 2 cores)")
        metafunc.parametrize("probe_case", [pytest.param(None, marks=skip)], ids=["probes"])
        return
    from tests import probes

    # Every probe's (family, id): the probes are built from the base's paths, not its files.
    cases = [(p.family, p.id) for family in probes.all_families().values() for p in family(probes.Base(Path("base")))]
    metafunc.parametrize("probe_case", cases, ids=[f"{f}:{i}" for f, i in cases])


@pytest.fixture(scope="session")
def base(tmp_path_factory: pytest.TempPathFactory):  # noqa: ANN201 - a tests.probes.Base
    """The probes' shared inputs: the tiny cities ingested and built, and two trained runs (made once)."""
    from tests import probes

    made = probes.Base(tmp_path_factory.mktemp("probes") / "base")
    made.make(600)
    return made


def test_probe(probe_case: tuple[str, str], base, tmp_path: Path) -> None:  # noqa: ANN001
    from tests import probes

    family, probe_id = probe_case
    probe = next(p for p in probes.all_families()[family](base) if p.id == probe_id)
    probes.classify(probe, tmp_path, 60.0)
    assert probe.outcome not in (*probes.BAD, "setup"), f"{probe.outcome}: {probe.detail}"
