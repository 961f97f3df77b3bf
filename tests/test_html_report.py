"""The HTML report in a real browser: headless Chromium (Debian's package) opens the page, runs it
without console errors, and the page it renders holds the parameter table's values and the
embedded figures (fit, residuals, stage-1 landscape, correlations). Skipped, with the reason, where
no Chromium is installed.

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


def _browser_runs(tmp_path) -> str | None:
    """Why the browser cannot render here (None where it renders a trivial page)."""
    if BROWSER is None:
        return "no Chromium on this machine (apt-get install chromium)"
    probe = tmp_path / "probe.html"
    probe.write_text("<!DOCTYPE html><html><body><p id='x'>ok</p></body></html>")
    try:
        run = subprocess.run([BROWSER, *FLAGS, f"--user-data-dir={tmp_path / 'probe_profile'}", "--dump-dom",
                              probe.as_uri()], capture_output=True, text=True, timeout=120)
    except (OSError, subprocess.TimeoutExpired) as err:
        return f"Chromium does not start here ({err})"
    return None if "id=\"x\"" in run.stdout else f"Chromium does not render here: {run.stderr[-300:]}"


def test_the_report_renders_in_a_browser_with_its_values_and_figures(tmp_path):
    cannot = _browser_runs(tmp_path)
    if cannot:
        pytest.skip(cannot)
    m = casest.load_model_file("scalar2")
    model, data = m.model(), m.simulate(seed=0)
    est = casest.estimate(model, data)
    page = tmp_path / "report.html"
    est.to_html(str(page), model=model, data=data)
    profile = tmp_path / "profile"
    run = subprocess.run([BROWSER, *FLAGS, f"--user-data-dir={profile}", "--enable-logging=stderr", "--v=0",
                          "--dump-dom", page.as_uri()], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    dom = run.stdout
    values = [float(v) for v in re.findall(r'<td class="value">([^<]+)</td>', dom)]
    np.testing.assert_allclose(values, est.theta, rtol=1e-9)
    # the fit, the residuals, stage 1's landscape and the correlations
    assert dom.count('src="data:image/png;base64,') >= 4 and 'id="conclusion"' in dom
    console_errors = [line for line in run.stderr.splitlines() if "CONSOLE" in line and "ERROR" in line.upper()]
    assert not console_errors, console_errors
    shot = tmp_path / "report.png"
    subprocess.run([BROWSER, *FLAGS, f"--user-data-dir={profile}", "--window-size=1280,1400",
                    f"--screenshot={shot}", page.as_uri()], capture_output=True, timeout=120)
    assert shot.exists() and shot.stat().st_size > 10_000


def test_the_page_holds_the_intervals_the_sets_and_the_data_figures():
    """With profile intervals and likelihood-ratio sets attached, and the model and its data given,
    the page lists each interval and set (the estimate's own numbers) and draws the fit, the
    residuals, the landscape and the correlations."""
    pytest.importorskip("matplotlib")
    from casest.two_stage import with_profile_intervals

    m = casest.load_model_file("scalar2")
    model, data = m.model(), m.simulate(seed=0)
    problem = casest.Problem(model, data)
    est = with_profile_intervals(casest.estimate(problem), problem)
    page = est.to_html(model=model, data=data)
    assert "id='intervals'" in page and "id='likelihood_sets'" in page
    for interval in est.intervals:
        assert f"<td>{interval.lower:.6g}</td><td>{interval.upper:.6g}</td>" in page
    assert page.count("data:image/png;base64,") >= 4



def test_a_page_drawn_with_another_model_or_no_records_is_refused():
    """The figures of a page are the estimate's model on its records: a model whose parameters
    are not the estimate's, or data that are not Datasets, would draw something else."""
    m = casest.load_model_file("scalar2")
    model, data = m.model(), m.simulate(0)
    est = casest.estimate(model, data, progress=False)
    with pytest.raises(casest.OptionError, match="give the model the result was estimated with"):
        est.to_html(model=casest.load_model_file("pitot5hole").model(), data=data)
    with pytest.raises(casest.OptionError, match="must be a casest.Dataset"):
        est.to_html(model=model, data={"a": 5})


def test_a_model_holding_some_of_the_estimates_parameters_is_refused_with_or_without_records():
    """scalar1's model (a, b, c) for scalar2's estimate (a, b, c, d): its parameters are all among the
    estimate's, and the page was drawn without a word; with or without records it is refused now,
    naming the parameter only in the result."""
    m = casest.load_model_file("scalar2")
    est = casest.estimate(m.model(), m.simulate(0), progress=False)
    other = casest.load_model_file("scalar1").model()
    for data in (m.simulate(0), None):
        with pytest.raises(casest.OptionError, match=r"\['d'\] only in the result"):
            est.to_html(model=other, data=data)
