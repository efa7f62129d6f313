"""Screenshots of the top of report pages in a headless Chromium, as a laptop shows them (docs/img/*-top.png).

    python experiments/screenshots.py reports/report.html reports/fleet/fleet.html --out docs/img

Needs Debian's chromium and chromium-driver and selenium (the test extra); tests/test_browser.py checks the same
pages in the same browser.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from selenium import webdriver

WIDTH, HEIGHT = 1366, 900


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("pages", nargs="+", type=Path, help="report pages (.html)")
    parser.add_argument("--out", type=Path, default=Path("docs/img"), help="folder of the screenshots")
    args = parser.parse_args()
    options = webdriver.ChromeOptions()
    options.binary_location = shutil.which("chromium") or "chromium"
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", f"--window-size={WIDTH},{HEIGHT}"):
        options.add_argument(arg)
    driver = webdriver.Chrome(service=webdriver.ChromeService(executable_path=shutil.which("chromedriver")), options=options)
    try:
        for page in args.pages:
            driver.get(page.resolve().as_uri())
            out = args.out / f"{page.stem}-top.png"
            driver.save_screenshot(str(out))
            print(out)
    finally:
        driver.quit()


if __name__ == "__main__":
    main()
