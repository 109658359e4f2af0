"""Fixtures of the app tests: one headless Chromium for every page a test session renders."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.app.browser import Chromium, browser_or_skip


@pytest.fixture(scope="session")
def chromium(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Chromium]:
    """The headless browser of this test session (of this worker, under xdist), started at its first page; the
    tests that ask for it skip when no browser is installed."""
    browser = Chromium(browser_or_skip(), tmp_path_factory.mktemp("chromium"))
    yield browser
    browser.close()
