"""The report pages in a real browser (headless Chromium through Selenium): every figure loads, no table runs off the
screen without a scroll box of its own, nothing errs in the console. Skipped, saying so, where no browser is
installed (Debian: apt-get install chromium chromium-driver; .ci/run installs them)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from tests.conftest import REPO

CHROMIUM, DRIVER = shutil.which("chromium") or shutil.which("chromium-browser"), shutil.which("chromedriver")
pytestmark = pytest.mark.skipif(
    CHROMIUM is None or DRIVER is None,
    reason="no headless browser here (chromium and chromedriver): apt-get install chromium chromium-driver",
)

#: A laptop's screen.
WIDTH, HEIGHT = 1366, 768


@pytest.fixture(scope="module")
def browser():
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed (the test extra has it)")
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", f"--window-size={WIDTH},{HEIGHT}"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=webdriver.ChromeService(executable_path=DRIVER), options=options)  # no download
    yield driver
    driver.quit()


@pytest.fixture(scope="module")
def pages(tmp_path_factory, tiny) -> dict[str, Path]:
    """The placement, tracking and fleet reports' pages, each played on a few episodes of the embedded tiny cities."""
    from uavplace.cli import uavrl
    from uavplace.dataset.build import build_city
    from uavplace.ingest.pipeline import ingest_city
    from uavplace.schemas.bundle import BuildConfig

    tmp = tmp_path_factory.mktemp("pages")
    root = tmp / "processed"
    shutil.copytree(tiny, root)
    ingest_city(REPO / "data" / "raw" / "tiny-routes", root)
    build_city("tiny-routes", BuildConfig(grid_m=4.0, altitude_m=10.0), root)
    common = ["--root", str(root), "--bootstrap", "100", "--quiet"]
    runs = {
        "placement": ["report", "--dataset", "tiny", "--episodes", "30", "--out", str(tmp / "placement")],
        "tracking": ["report", "--task", "tracking", "--dataset", "tiny-routes", "--episodes", "4", "--horizon", "60",
                     "--out", str(tmp / "tracking")],
        "fleet": ["report", "--task", "fleet", "--dataset", "tiny", "--episodes", "6", "--users", "2", "--out",
                  str(tmp / "fleet")],
    }  # fmt: skip
    found = {}
    for task, args in runs.items():
        res = CliRunner().invoke(uavrl, [*args, *common])
        assert res.exit_code == 0, res.output
        found[task] = next(p for p in Path(args[args.index("--out") + 1]).glob("*.html"))
    return found


@pytest.mark.parametrize("task", ["placement", "tracking", "fleet"])
def test_a_report_page_shows_in_a_browser(browser, pages, task):
    browser.get(pages[task].resolve().as_uri())
    images = browser.execute_script(
        "return [...document.images].map(i => [i.alt, i.complete && i.naturalWidth > 0, i.getBoundingClientRect().right])"
    )
    assert images and all(loaded for _, loaded, _ in images), images  # every figure decoded
    width = browser.execute_script("return window.innerWidth")
    assert all(right <= width + 1 for _, _, right in images), images  # no figure runs off the screen
    # A table wider than the screen scrolls in a box of its own: the page never scrolls sideways.
    assert browser.execute_script("return document.documentElement.scrollWidth") <= width
    tables = browser.execute_script(
        "return [...document.querySelectorAll('table')].map(t => [t.getBoundingClientRect().right, t.scrollWidth,"
        " t.clientWidth, getComputedStyle(t).overflowX])"
    )
    for right, scroll, client, overflow in tables:
        assert right <= width + 1 and (scroll <= client + 1 or overflow in ("auto", "scroll")), tables
    errors = [e for e in browser.get_log("browser") if e["level"] == "SEVERE"]
    assert not errors, errors


@pytest.mark.parametrize("task", ["placement", "tracking", "fleet"])
def test_a_page_leads_with_what_it_found_on_the_first_screen(browser, pages, task):
    browser.get(pages[task].resolve().as_uri())
    found = browser.execute_script(
        "const l = document.querySelector('ul.findings'); return [l.getBoundingClientRect().top, l.children.length]"
    )
    assert 0 <= found[0] < HEIGHT / 2 and found[1] >= 1, found  # on the first screen, not below the tables
