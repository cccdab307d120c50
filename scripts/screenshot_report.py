#!/usr/bin/env python3
"""Look at a report in a real browser: headless Chromium's screenshot of its first screen.

    python scripts/screenshot_report.py REPORT.html [-o first_screen.png] [--size 1280x900]

Chromium comes from Debian (``scripts/install_debian.sh chromium``).  The page is opened as
a file, as a reader opens report.html, and the screenshot is of the window (the first
screen).  Prints how much of it is not background and how much is colour (only the
figures are coloured: text is black or grey), and exits 1 when the screenshot is blank or
shows no figure, 3 when no Chromium is installed.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Browsers tried, in order (Debian names the binary ``chromium``).
BROWSERS = ("chromium", "chromium-browser")

#: A pixel differs from the background by more than this in some channel (0..1): "ink".
INK = 0.05
#: A pixel whose channels spread by more than this is coloured (not black, white or grey).
COLOUR = 0.2


@dataclass(frozen=True)
class Look:
    """What a screenshot shows: its size and the shares of ink and colour pixels."""

    width: int
    height: int
    ink: float
    colour: float

    @property
    def blank(self) -> bool:
        return self.ink < 0.01

    @property
    def has_figure(self) -> bool:
        return self.colour > 0.001


def find_browser() -> str | None:
    """The path of an installed Chromium, or None."""
    return next((path for name in BROWSERS if (path := shutil.which(name))), None)


def screenshot(page: Path, png: Path, width: int = 1280, height: int = 900,
               browser: str | None = None, timeout: float = 120) -> Path:
    """Write headless Chromium's screenshot of ``page`` (its first ``width`` x ``height``
    pixels) to ``png``.  RuntimeError with Chromium's output when no PNG comes out."""
    browser = browser or find_browser()
    if browser is None:
        raise FileNotFoundError("no Chromium found (scripts/install_debian.sh chromium)")
    png = Path(png).resolve()
    png.unlink(missing_ok=True)
    with tempfile.TemporaryDirectory() as profile:  # no shared profile, no lock to meet
        cmd = [browser, "--headless", "--no-sandbox",  # root cannot use the sandbox
               "--disable-gpu", "--hide-scrollbars", "--no-first-run",
               f"--user-data-dir={profile}", f"--window-size={width},{height}",
               f"--screenshot={png}", Path(page).resolve().as_uri()]
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    if not png.exists() or png.stat().st_size == 0:
        raise RuntimeError(f"{browser} wrote no screenshot (exit {res.returncode}): "
                           f"{(res.stderr or res.stdout).strip()[-800:]}")
    return png


def look(png: Path) -> Look:
    """Measure a screenshot: ink is any pixel away from the most common colour."""
    import matplotlib.image

    rgb = np.asarray(matplotlib.image.imread(png), dtype=np.float64)[..., :3]
    pixels = rgb.reshape(-1, 3)
    values, counts = np.unique(np.round(pixels * 255).astype(np.int64), axis=0,
                               return_counts=True)
    background = values[np.argmax(counts)] / 255
    ink = (np.abs(pixels - background) > INK).any(axis=1)
    colour = (pixels.max(axis=1) - pixels.min(axis=1)) > COLOUR
    return Look(rgb.shape[1], rgb.shape[0], float(ink.mean()), float(colour.mean()))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("page", type=Path, help="report.html")
    parser.add_argument("-o", "--output", type=Path, default=Path("first_screen.png"))
    parser.add_argument("--size", default="1280x900", help="window WIDTHxHEIGHT")
    args = parser.parse_args(argv)
    if not args.page.is_file():
        parser.error(f"no such page: {args.page}")
    width, height = (int(v) for v in args.size.lower().split("x"))
    if find_browser() is None:
        print("no Chromium found: install it with scripts/install_debian.sh chromium",
              file=sys.stderr)
        return 3
    png = screenshot(args.page, args.output, width, height)
    seen = look(png)
    print(f"{png}: {seen.width} x {seen.height}, ink {seen.ink:.1%}, colour {seen.colour:.1%}")
    if seen.blank or not seen.has_figure:
        print("the first screen is blank" if seen.blank else
              "the first screen shows no figure", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
