"""Pages as headless Chromium renders them: the screenshot tests of reports and dashboard."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest

CHROMIUM = Path("/usr/bin/chromium")


def chromium_or_skip() -> Path:
    """Chromium's path; under CI=true its absence fails, elsewhere the test skips."""
    if CHROMIUM.exists():
        return CHROMIUM
    if os.environ.get("CI"):
        pytest.fail(f"{CHROMIUM} is missing: CI must install the Debian package chromium")
    pytest.skip(f"{CHROMIUM} is not installed (apt-get install chromium); CI runs this test")


def screenshot(page: Path | str, out: Path, height: int) -> np.ndarray:
    """A file or a URL as Chromium renders it 1280 px wide, as RGB in 0..1."""
    browser = chromium_or_skip()
    shot = out / "shot.png"
    command = [
        str(browser),
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--no-proxy-server",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={out / 'profile'}",
        f"--screenshot={shot}",
        f"--window-size=1280,{height}",
        page.resolve().as_uri() if isinstance(page, Path) else page,
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=180, check=False)
    assert done.returncode == 0 and shot.exists(), done.stderr[-2000:]
    image = np.asarray(matplotlib.image.imread(shot), dtype=np.float64)
    shutil.rmtree(out / "profile", ignore_errors=True)
    shot.unlink()
    return image[:, :, :3]


def pixels_like(image: np.ndarray, colour: str, tolerance: float = 0.06) -> int:
    """How many pixels have the colour ``#rrggbb`` (each channel within ``tolerance``)."""
    target = np.array([int(colour[i : i + 2], 16) / 255 for i in (1, 3, 5)])
    return int(np.count_nonzero(np.all(np.abs(image - target) <= tolerance, axis=2)))
