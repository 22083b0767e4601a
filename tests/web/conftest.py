"""The browser tests' ``browser`` (one Chromium per module) and ``page`` (a fresh 1366x768 context per test), and
the web tests' audit log: a test that uses a module's demo site (``site``, harness.web_demo) audits into the
site's file, which its history recorder follows.

The suite's own autouse fixture points ``STARTERBUS_AUDIT_LOG`` at each test's temporary folder; the demo's
bus workers open a device (and its audit log, from that variable) when they first reach it or reconnect, which
may happen during any test. Without this, a write through the page could be audited into the test's folder,
unseen by the site's recorder and its ``audit_records()``.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from starterbus.core.audit import ENV_VAR
from starterbus.tests.web.harness import WebDemo


@pytest.fixture(autouse=True)
def _the_sites_audit_log(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> None:
    if "site" in request.fixturenames:
        site = request.getfixturevalue("site")
        if isinstance(site, WebDemo):
            monkeypatch.setenv(ENV_VAR, str(site.audit))


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    from starterbus.tests.web.chromium import CHROMIUM, sync_api

    with sync_api.sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        try:
            yield chromium
        finally:
            chromium.close()


@pytest.fixture
def page(browser: Any) -> Iterator[Any]:
    context = browser.new_context(viewport={"width": 1366, "height": 768})
    try:
        yield context.new_page()
    finally:
        context.close()
