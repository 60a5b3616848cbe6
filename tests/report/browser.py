"""Headless Chromium driven by Selenium, for the report page's tests: Debian's
`chromium` and `chromium-driver` (no browser download), or the test skips saying why."""

from __future__ import annotations

import shutil
import tempfile
import time

import pytest

# A closed network refuses Chromium's background connections unless they are turned off.
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--enable-unsafe-swiftshader",
    "--window-size=1100,1500",
    "--hide-scrollbars",
)


def find_chromium() -> tuple[str, str]:
    """(browser, driver) paths, or pytest.skip naming what is missing."""
    browser = next((p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None)
    driver = shutil.which("chromedriver")
    if browser is None or driver is None:
        pytest.skip(
            "no Chromium found (install Debian's chromium and chromium-driver to run the browser tests): "
            f"browser {browser or 'missing'}, chromedriver {driver or 'missing'}"
        )
    return browser, driver


def start_browser():
    """A headless Chromium session with its console log kept."""
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        pytest.skip("selenium is not installed (pip install -e '.[test]')")
    browser, driver = find_chromium()
    options = webdriver.ChromeOptions()
    options.binary_location = browser
    for flag in FLAGS:
        options.add_argument(flag)
    options.add_argument(f"--user-data-dir={tempfile.mkdtemp(prefix='graphsvc-chromium-')}")
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(driver), options=options)


def open_page(driver, path, timeout_s: float = 20.0) -> None:
    """Load a page from a file and wait for the viewer's hook."""
    driver.get(path.resolve().as_uri())
    end = time.monotonic() + timeout_s
    while not driver.execute_script("return !!(window.graphsvcViewer && window.graphsvcViewer.ready)"):
        if time.monotonic() > end:
            raise AssertionError(f"the viewer did not start; console: {driver.get_log('browser')}")
        time.sleep(0.05)


def console_errors(driver) -> list[str]:
    return [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE"]


def wait_for(predicate, timeout_s: float = 5.0, step_s: float = 0.05):
    end = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value or time.monotonic() > end:
            return value
        time.sleep(step_s)
