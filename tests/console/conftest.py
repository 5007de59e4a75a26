"""Fixtures: a fresh lluavd per test, one headless Chromium per module."""

from __future__ import annotations

import shutil

import pytest

from harness import SCREENSHOTS, Lluavd, chromium, lluavd_binary
from page import Page

PASSWORD = "s3cret"


@pytest.fixture(scope="session")
def binary() -> str:
    return lluavd_binary()


@pytest.fixture
def daemon(binary):
    """lluavd with a password, the simulator at four times real speed."""
    d = Lluavd(binary, "--password", PASSWORD, "--sim-speed", "4")
    yield d
    print(f"lluavd stderr:\n{d.stderr()[-4000:]}")  # shown when the test failed
    d.stop()


@pytest.fixture
def real_time_daemon(binary):
    """lluavd with a password, the simulator at real speed: a failsafe the
    test starts lasts long enough to be seen and overridden on a slow
    machine."""
    d = Lluavd(binary, "--password", PASSWORD)
    yield d
    print(f"lluavd stderr:\n{d.stderr()[-4000:]}")  # shown when the test failed
    d.stop()


@pytest.fixture
def open_daemon(binary):
    """lluavd without a password."""
    d = Lluavd(binary, "--sim-speed", "4")
    yield d
    print(f"lluavd stderr:\n{d.stderr()[-4000:]}")  # shown when the test failed
    d.stop()


@pytest.fixture(scope="module")
def browser():
    driver = chromium()
    yield driver
    driver.quit()
    shutil.rmtree(driver.profile_dir, ignore_errors=True)


@pytest.fixture
def page(browser):
    """The browser, on a blank page at the start; after the test, it fails
    the test if the page logged an error (a script error, a CSP violation,
    a failed load). Ask for it after the daemon so that it is checked
    while the daemon still runs."""
    browser.get("about:blank")
    browser.get_log("browser")
    p = Page(browser)
    yield p
    severe = [e for e in browser.get_log("browser") if e["level"] == "SEVERE"]
    browser.get("about:blank")
    assert severe == [], f"the page logged errors: {severe}"


@pytest.fixture(scope="session", autouse=True)
def screenshots_dir():
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    return SCREENSHOTS
