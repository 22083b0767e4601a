"""What the browser tests share: Debian's Chromium driven by Playwright (its ``executable_path``), skipped where
either is missing; the ``browser`` and ``page`` fixtures are in this folder's conftest."""

from __future__ import annotations

import shutil

import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install playwright)")
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="no chromium (apt-get install chromium)")
WAIT_MS = 20_000
