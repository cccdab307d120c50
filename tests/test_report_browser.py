"""The report looked at in a real browser: headless Chromium's screenshot of report.html's
first screen (scripts/screenshot_report.py) is neither blank nor without its figure.
Skipped, with the reason, where no Chromium is installed (scripts/install_debian.sh
chromium installs Debian's)."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "screenshot_report.py"


def _script():
    spec = importlib.util.spec_from_file_location("screenshot_report", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


shot = _script()


@pytest.fixture(scope="module")
def chromium() -> str:
    browser = shot.find_browser()
    if browser is None:
        pytest.skip("no Chromium installed (scripts/install_debian.sh chromium installs "
                    "Debian's)")
    return browser


def test_the_report_s_first_screen_shows_the_sentence_and_the_ratio_plot(made, chromium,
                                                                          tmp_path):
    _, report = made
    png = tmp_path / "first_screen.png"
    res = subprocess.run([sys.executable, str(SCRIPT), str(report / "report.html"), "-o",
                          str(png), "--size", "1280x900"], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    seen = shot.look(png)
    assert (seen.width, seen.height) == (1280, 900)
    assert not seen.blank and seen.has_figure
    assert f"ink {seen.ink:.1%}" in res.stdout


def test_a_page_without_a_figure_is_told_apart(chromium, tmp_path):
    """The check can fail: an empty page is blank, a page of text shows no figure."""
    for body, blank in (("", True), ("<h1>" + "words " * 400 + "</h1>", False)):
        page = tmp_path / "page.html"
        page.write_text(f"<!DOCTYPE html><html><body>{body}</body></html>")
        seen = shot.look(shot.screenshot(page, tmp_path / "page.png", 800, 600, chromium))
        assert seen.blank == blank and not seen.has_figure
        res = subprocess.run([sys.executable, str(SCRIPT), str(page), "-o",
                              str(tmp_path / "cli.png")], capture_output=True, text=True)
        assert res.returncode == 1
        assert ("blank" if blank else "shows no figure") in res.stderr
