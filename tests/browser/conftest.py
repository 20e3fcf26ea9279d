"""Headless Chromium for the browser tests (mark them ``@pytest.mark.browser``).

The browser is Debian's ``chromium`` package (``/usr/bin/chromium``, installed by scripts/setup.sh on
the Debian path; ``$MODALFEM_CHROMIUM`` names another binary), driven by Playwright from PyPI (test
extras). Playwright's own browser download is not used. WebGL runs on SwiftShader (software GL),
which Chromium only allows with ``--enable-unsafe-swiftshader``; ``--no-sandbox`` because tests may
run as root. Without Playwright or the browser every browser test is skipped with the reason.

Fixtures:
  * ``chromium`` (session): the launched Playwright ``Browser``.
  * ``open_page``: ``open_page(target, *, viewport=(800, 600)) -> BrowserPage`` for a URL or a local
    file path; each page records its console messages and uncaught errors and is closed at teardown.
  * ``page`` and ``page_errors``: one blank Playwright page (800 x 600, in its own context) and the
    list its console errors and uncaught exceptions are appended to, for tests that navigate themselves.

``BrowserPage.errors()`` lists the console errors and uncaught exceptions; ``BrowserPage.pixels()``
takes a screenshot as an (h, w, 3) uint8 array.
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

CHROMIUM = os.environ.get("MODALFEM_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = ["--enable-unsafe-swiftshader", "--no-sandbox"]


@dataclass
class BrowserPage:
    """A Playwright page with what it logged.

    Attributes:
        page: the Playwright ``Page``.
        messages: ``(type, text)`` of every console message (``"log"``, ``"warning"``, ``"error"``, ...).
        exceptions: text of every uncaught page error.
    """

    page: object
    messages: list = field(default_factory=list)
    exceptions: list = field(default_factory=list)

    def errors(self) -> list[str]:
        """Console errors and uncaught exceptions, in order of type."""
        return [text for kind, text in self.messages if kind == "error"] + list(self.exceptions)

    def pixels(self, **kwargs) -> np.ndarray:
        """Screenshot (h, w, 3) uint8 RGB (keyword options of ``Page.screenshot``)."""
        from PIL import Image

        png = self.page.screenshot(**kwargs)
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


@pytest.fixture(scope="session")
def chromium():
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("Playwright is not installed (pip install -e .[test])")
    if not os.access(CHROMIUM, os.X_OK):
        pytest.skip(f"no Chromium at {CHROMIUM} (Debian: apt-get install chromium, done by scripts/setup.sh; "
                    "or set MODALFEM_CHROMIUM)")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        try:
            yield browser
        finally:
            browser.close()


@pytest.fixture()
def open_page(chromium):
    contexts = []

    def open_(target, *, viewport=(800, 600)) -> BrowserPage:
        context = chromium.new_context(viewport={"width": viewport[0], "height": viewport[1]})
        contexts.append(context)
        page = context.new_page()
        bp = BrowserPage(page)
        page.on("console", lambda m: bp.messages.append((m.type, m.text)))
        page.on("pageerror", lambda e: bp.exceptions.append(str(e)))
        url = str(target)
        if "://" not in url:
            url = Path(url).absolute().as_uri()
        page.goto(url)
        return bp

    yield open_
    for context in contexts:
        context.close()


@pytest.fixture()
def page_errors() -> list:
    """Console errors and uncaught exceptions of the ``page`` fixture's page, as they happen."""
    return []


@pytest.fixture()
def page(chromium, page_errors):
    context = chromium.new_context(viewport={"width": 800, "height": 600})
    p = context.new_page()
    p.on("console", lambda m: page_errors.append(m.text) if m.type == "error" else None)
    p.on("pageerror", lambda e: page_errors.append(str(e)))
    try:
        yield p
    finally:
        context.close()
