"""Test configuration.

* Hypothesis runs derandomized by default, so that CI results are reproducible. With
  ``DEPTHGUARD_HYPOTHESIS=random`` (``make test-random``) every property test draws fresh examples, and
  ``DEPTHGUARD_HYPOTHESIS_SCALE`` (default 5) times as many as it declares.
* ``DEPTHGUARD_REQUIRE_EXTRAS=1`` (set by ``make test``, which installs every extra) turns a skipped test
  into a failure: a missing extra must not hide core tests there. Only the skips in :data:`ALLOWED_SKIPS`
  (the machine lacks something no extra installs, listed in the README) stay skips. Without the variable,
  plain ``pytest`` without the extras still skips with the reason.
"""

from __future__ import annotations

import os

import pytest
from hypothesis import settings

settings.register_profile("depthguard", derandomize=True, print_blob=True)
settings.register_profile("random", derandomize=False, print_blob=True)
RANDOM = os.environ.get("DEPTHGUARD_HYPOTHESIS", "") == "random"
settings.load_profile("random" if RANDOM else "depthguard")

REQUIRE_EXTRAS = os.environ.get("DEPTHGUARD_REQUIRE_EXTRAS", "") not in ("", "0")

#: Skip reasons (prefixes) that stay skips under ``DEPTHGUARD_REQUIRE_EXTRAS=1``: nothing pip can install.
ALLOWED_SKIPS = (
    "renderer unavailable",
    "no OpenGL context",
    "no headless Chromium at",  # Debian chromium-headless-shell (.ci/run installs it)
    "pyrealsense2 does not import here",  # the wheel needs the system libusb (.ci/run installs it)
    "the openssl command is needed",
)


def pytest_collection_modifyitems(config, items):
    if not RANDOM:
        return
    scale = int(os.environ.get("DEPTHGUARD_HYPOTHESIS_SCALE", "5"))
    seen: set[int] = set()
    for item in items:
        fn = getattr(item, "obj", None)
        current = getattr(fn, "_hypothesis_internal_use_settings", None)
        if current is None or id(fn) in seen:
            continue
        seen.add(id(fn))
        fn._hypothesis_internal_use_settings = settings(
            current, max_examples=current.max_examples * scale, derandomize=False
        )


def _forbidden_skip(report) -> str | None:
    if not (REQUIRE_EXTRAS and report.skipped) or hasattr(report, "wasxfail"):
        return None
    longrepr = report.longrepr
    reason = longrepr[2] if isinstance(longrepr, tuple) and len(longrepr) == 3 else str(longrepr)
    reason = reason.removeprefix("Skipped: ")
    if reason.startswith(ALLOWED_SKIPS):
        return None
    return reason


def _to_failure(report, reason: str) -> None:
    report.outcome = "failed"
    report.longrepr = (
        f"skipped under DEPTHGUARD_REQUIRE_EXTRAS=1 (make test installs every extra): {reason}\n"
        "Install the extra (pip install -e '.[all]') or, if nothing pip can install provides it, "
        "add the reason to ALLOWED_SKIPS in tests/conftest.py and to the README's list of skips."
    )


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    reason = _forbidden_skip(report)
    if reason is not None:
        _to_failure(report, reason)


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    outcome = yield
    report = outcome.get_result()
    reason = _forbidden_skip(report)
    if reason is not None:
        _to_failure(report, reason)
