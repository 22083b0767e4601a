"""The web tests' audit log: a test that uses a module's demo site (``site``, harness.web_demo) audits into the
site's file, which its history recorder follows.

The suite's own autouse fixture points ``STARTERBUS_AUDIT_LOG`` at each test's temporary folder; the demo's
bus workers open a device (and its audit log, from that variable) when they first reach it or reconnect, which
may happen during any test. Without this, a write through the page could be audited into the test's folder,
unseen by the site's recorder and its ``audit_records()``.
"""

from __future__ import annotations

import pytest

from starterbus.core.audit import ENV_VAR
from starterbus.tests.web.harness import WebDemo


@pytest.fixture(autouse=True)
def _the_sites_audit_log(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> None:
    if "site" in request.fixturenames:
        site = request.getfixturevalue("site")
        if isinstance(site, WebDemo):
            monkeypatch.setenv(ENV_VAR, str(site.audit))
