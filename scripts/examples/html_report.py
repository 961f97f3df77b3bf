#!/usr/bin/env python3
"""The AP2 air-data calibration as one self-contained HTML page, and a screenshot of it.

    python3 scripts/examples/html_report.py [--out DIR] [--screenshot]

Runs the air-data estimate of ``scripts/examples/ampyx_example.py`` (the bundled Ampyx AP2 record,
windows s1 + s2) and writes ``DIR/ampyx_air_data_report.html`` (default DIR: a new folder
``casest_report`` in the working directory); with ``--screenshot`` also
``DIR/ampyx_air_data_report.png``, taken by headless Chromium (``apt-get install chromium``).
The docs' screenshot is made by ``--out docs/figures --screenshot``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", ".."))
sys.path.insert(0, HERE)

import casest  # noqa: E402
from ampyx_example import WINDOWS  # noqa: E402

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def screenshot(page: str, png: str) -> None:
    """A 1280 px wide screenshot of ``page`` by headless Chromium."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if browser is None:
        raise SystemExit("no Chromium found for the screenshot: apt-get install chromium")
    with tempfile.TemporaryDirectory(prefix="casest_chromium_") as profile:
        subprocess.run([browser, *FLAGS, f"--user-data-dir={profile}", "--window-size=1280,1500",
                        "--hide-scrollbars", f"--screenshot={os.path.abspath(png)}",
                        "file://" + os.path.abspath(page)], check=True, capture_output=True, timeout=120)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=os.path.join(os.getcwd(), "casest_report"), help="folder of the page")
    parser.add_argument("--screenshot", action="store_true", help="also a PNG screenshot (headless Chromium)")
    args = parser.parse_args(argv)
    module = casest.load_model_file("ampyx_air_data")
    train = module.load((WINDOWS["s1"][0], WINDOWS["s2"][1]))
    est = casest.estimate(module.model(), train, sweep_settings=module.SWEEP_SETTINGS,
                          solver_settings=casest.SolverSettings(record_iterates=True))
    os.makedirs(args.out, exist_ok=True)
    page = os.path.join(args.out, "ampyx_air_data_report.html")
    est.to_html(page, title="Ampyx AP2: air-data calibration (windows s1 + s2)", model=module.model(), data=train)
    print("wrote", page)
    if args.screenshot:
        png = page[:-5] + ".png"
        screenshot(page, png)
        print("wrote", png)
    return 0


if __name__ == "__main__":
    sys.exit(main())
