"""Headless Chromium (Debian's) driven by Playwright, shared by the browser tests."""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Generator, Iterator
from pathlib import Path

import pytest
from playwright.sync_api import Browser, Page, Playwright, expect, sync_playwright

from tests.factories import totp_secret_of, unused_totp_code

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
# A failed test's pages are photographed into var/ always: never among the documentation's
# pictures, which `make screenshots` writes to SCREENSHOT_DIR.
FAILURE_SHOTS = Path(__file__).resolve().parents[2] / "var" / "screenshots"
SCREENSHOTS = Path(os.environ.get("SCREENSHOT_DIR", FAILURE_SHOTS))
# `make screenshots` asks for the pictures of every page; otherwise only failures are kept.
EVERY_PAGE_PHOTOGRAPHED = "SCREENSHOT_DIR" in os.environ


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    assert Path(CHROMIUM).exists(), "Chromium is missing: `make test` installs it (apt chromium)"
    # Playwright's sync API runs an event loop in this thread; the test's own ORM calls are
    # synchronous and safe, which Django cannot tell.
    os.environ["DJANGO_ALLOW_ASYNC_UNSAFE"] = "true"
    playwright = _start_playwright()
    try:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield browser
        browser.close()
    finally:
        playwright.stop()


# Playwright's driver (a node process) answered its first call in under a second in every
# run but one, where the handshake never came and the module's tests waited out their
# timeout. A driver that has not answered by then is killed and started once more.
DRIVER_START_S = 60.0


def _driver_processes() -> set[int]:
    """This process's children that are Playwright drivers."""
    found = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            command = (stat.parent / "cmdline").read_bytes()
        except (OSError, ValueError, IndexError):
            continue
        if ppid == os.getpid() and b"playwright" in command and b"driver" in command:
            found.add(int(stat.parent.name))
    return found


def _start_playwright() -> Playwright:
    before = _driver_processes()
    for attempt in (1, 2):
        started = threading.Event()

        def watchdog(started: threading.Event = started) -> None:
            if not started.wait(DRIVER_START_S):
                for pid in _driver_processes() - before:
                    sys.stderr.write(f"Playwright's driver {pid} did not answer: killed\n")
                    os.kill(pid, signal.SIGKILL)

        guard = threading.Thread(target=watchdog, daemon=True)
        guard.start()
        try:
            playwright = sync_playwright().start()
        except Exception:
            if attempt == 2:
                raise
            continue
        finally:
            started.set()
        return playwright
    raise AssertionError("unreachable")


def login(page: Page, web: str, username: str, password: str) -> None:
    page.goto(f"{web}/")
    expect(page).to_have_url(f"{web}/accounts/login/?next=/")
    page.get_by_label("Username or email").fill(username)
    page.get_by_label("Password").fill(password)
    page.get_by_role("button", name="Log in").click()
    secret = totp_secret_of(username)
    if secret is not None:
        # Two-factor authentication on (every staff account): the code its app shows now.
        expect(page).to_have_url(f"{web}/accounts/2fa/authenticate/")
        page.locator("input[name=code]").fill(unused_totp_code(secret))
        page.get_by_role("button", name="Sign In").click()
    expect(page.get_by_role("heading", name=f"Hello, {username}")).to_be_visible()


# What a failed browser test leaves behind: each open page's address, console, uncaught errors
# and last requests in the report, and a screenshot beside the others. A failure on a loaded
# machine is then read from the run's output, not guessed at.
REPORT_REQUESTS = 30


def _page_report(page: Page, name: str) -> list[str]:
    lines = [f"page {name}: {page.url}"]
    lines += [f"  console {m.type}: {m.text}" for m in page.console_messages()]
    lines += [f"  uncaught: {error}" for error in page.page_errors()]
    asked = [r for r in page.requests() if "/static/" not in r.url]
    for request in asked[-REPORT_REQUESTS:]:
        took_ms = request.timing["responseEnd"]
        timed = f"{took_ms:.0f} ms" if took_ms >= 0 else "not timed (still waiting, or cached)"
        outcome = request.failure or timed
        lines.append(f"  {request.method} {request.url} · {outcome}")
    return lines


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(
    item: pytest.Item, call: pytest.CallInfo[None]
) -> Generator[None, pytest.TestReport, pytest.TestReport]:
    report = yield
    browser = getattr(item, "funcargs", {}).get("browser")
    if report.when != "call" or not report.failed or browser is None:
        return report
    lines: list[str] = []
    for c, context in enumerate(browser.contexts):
        for p, page in enumerate(context.pages):
            name = f"{c}.{p}"
            try:
                lines += _page_report(page, name)
                FAILURE_SHOTS.mkdir(parents=True, exist_ok=True)
                shot = FAILURE_SHOTS / f"failed-{item.name}-{name}.png"
                page.screenshot(path=str(shot), full_page=True)
                lines.append(f"  screenshot: {shot.name}")
            except Exception as error:  # a page that crashed: say so, keep the test's failure
                lines.append(f"  (could not be read: {error})")
    if lines:
        report.sections.append(("open pages", "\n".join(lines)))
    return report
