"""The HTML report in a real browser: headless Chromium (Debian's package) opens the page, runs it
without console errors, and the page it renders holds the parameter table's values and the
embedded figures. Skipped, with the reason, where no Chromium is installed.

Truth: the estimate's own values (the rendered table against ``est.theta``), the browser's
console (no message at error level), the rendered DOM (the figures' <img> elements).
"""

import re
import shutil
import subprocess

import numpy as np
import pytest

import casest

BROWSER = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


@pytest.mark.skipif(BROWSER is None, reason="no Chromium on this machine (apt-get install chromium)")
def test_the_report_renders_in_a_browser_with_its_values_and_figures(tmp_path):
    m = casest.load_model_file("scalar2")
    est = casest.estimate(m.model(), m.simulate(seed=0))
    page = tmp_path / "report.html"
    est.to_html(str(page))
    profile = tmp_path / "profile"
    run = subprocess.run([BROWSER, *FLAGS, f"--user-data-dir={profile}", "--enable-logging=stderr", "--v=0",
                          "--dump-dom", page.as_uri()], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    dom = run.stdout
    values = [float(v) for v in re.findall(r'<td class="value">([^<]+)</td>', dom)]
    np.testing.assert_allclose(values, est.theta, rtol=1e-9)
    assert dom.count('src="data:image/png;base64,') >= 1 and 'id="conclusion"' in dom
    console_errors = [line for line in run.stderr.splitlines() if "CONSOLE" in line and "ERROR" in line.upper()]
    assert not console_errors, console_errors
    shot = tmp_path / "report.png"
    subprocess.run([BROWSER, *FLAGS, f"--user-data-dir={profile}", "--window-size=1280,1400",
                    f"--screenshot={shot}", page.as_uri()], capture_output=True, timeout=120)
    assert shot.exists() and shot.stat().st_size > 10_000
