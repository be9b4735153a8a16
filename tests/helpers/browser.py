"""A headless Chromium for end-to-end tests of the dashboard (Debian's chromium and
chromium-driver, driven by selenium; scripts/test.py installs them).  Nothing is downloaded:
the browser and its driver are the system's, or the tests are skipped."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from selenium.webdriver.remote.webdriver import WebDriver

#: Flags for a root user in a container: no sandbox, no GPU, no shared memory, nothing fetched.
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                  "--no-first-run", "--disable-background-networking", "--disable-component-update",
                  "--disable-sync", "--hide-scrollbars", "--force-device-scale-factor=1")


def find_chromium() -> tuple[str, str] | None:
    """(browser, driver) paths of the system's Chromium and chromedriver, or None."""
    browser = next((p for p in ("/usr/bin/chromium", shutil.which("chromium"),
                                shutil.which("chromium-browser")) if p and os.access(p, os.X_OK)), None)
    driver = next((p for p in ("/usr/bin/chromedriver", shutil.which("chromedriver"))
                   if p and os.access(p, os.X_OK)), None)
    return (browser, driver) if browser and driver else None


def missing_reason() -> str | None:
    """Why browser tests cannot run here (None: they can)."""
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install -e '.[test]')"
    if find_chromium() is None:
        return "chromium and chromium-driver are not installed (apt-get install chromium chromium-driver)"
    return None


class HeadlessChromium:
    """A selenium driver on a fresh profile directory, removed again by :meth:`quit`."""

    def __init__(self, width: int = 1400, height: int = 1000, flags: tuple[str, ...] = ()) -> None:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service

        found = find_chromium()
        if found is None:
            raise RuntimeError(missing_reason() or "no chromium")
        browser, driver = found
        self.profile = Path(tempfile.mkdtemp(prefix="tmcl-chromium-"))
        options = webdriver.ChromeOptions()
        options.binary_location = browser
        for flag in (*CHROMIUM_FLAGS, *flags):
            options.add_argument(flag)
        options.add_argument(f"--user-data-dir={self.profile}")
        options.add_argument(f"--window-size={width},{height}")
        self.driver: WebDriver = webdriver.Chrome(service=Service(driver), options=options)

    def quit(self) -> None:
        try:
            self.driver.quit()
        finally:
            shutil.rmtree(self.profile, ignore_errors=True)
