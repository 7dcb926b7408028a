"""The operator page of a two-scanner cell in a real browser: a card per scanner, a dry run of
both started from the page and followed scanner by scanner, then one scanner chosen (its
history, exports and scan picture) and verified; a screenshot of the page."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from selenium.webdriver.support.ui import Select

from tests.browser.test_page import (
    RUN_TIMEOUT_S,
    TERMINAL,
    _answer_confirmation,
    _by_id,
    _check_plot_labels,
    _click,
    _enter_token,
    _get,
    _screenshot,
    _wait,
)
from tests.daemon_helpers import DaemonProcess

pytestmark = [pytest.mark.slow, pytest.mark.integration, pytest.mark.timeout(600)]

SCANNERS = ("front", "rear")


def _card_css(name: str) -> str:
    return f'#scanner-cards .scanner-card[data-scanner="{name}"]'


def _card(browser: Any, name: str) -> Any:
    return browser.find_element("css selector", _card_css(name))


def _card_text(browser: Any, name: str) -> str:
    """A card's text, found and read again if the page re-rendered it in between (it does on
    every event: a bare ``_card(...).text`` can meet a stale element)."""
    return str(_wait(browser, lambda d: _card(d, name).text, f"{name}'s card"))


def _seen(browser: Any, css: str) -> bool:
    found = browser.find_elements("css selector", css)
    return bool(found) and found[0].is_displayed()


def test_a_cell_scanner_by_scanner(cell_daemon: DaemonProcess, browser: Any, artifacts: Path) -> None:
    browser.get(cell_daemon.url + "/")
    _wait(browser, lambda d: all("connected" in _card(d, name).text for name in SCANNERS),
          "both scanners' cards")
    _wait(browser, lambda d: _by_id(d, "stream-state").text == "stream: live", "the live event stream")
    assert not _seen(browser, "#scanner-status"), "a cell shows its scanners' cards, not one scanner line"
    assert all("no active calibration" in _card_text(browser, name) for name in SCANNERS)
    _wait(browser, lambda d: d.find_elements("css selector", "#preset option[value^='each']"),
          "the trajectories")
    chosen = Select(_by_id(browser, "preset")).first_selected_option.text
    assert chosen.startswith("each scanner's own (16 waypoints"), chosen  # 8 per scanner, chosen first

    # One dry run of every scanner, started from the page, followed scanner by scanner.
    _by_id(browser, "activate-on-pass").click()
    _by_id(browser, "start-dry-run").click()
    assert "every scanner" in _answer_confirmation(browser, yes=True)
    _enter_token(browser, cell_daemon.token)
    _wait(browser, lambda d: _by_id(d, "progress-text").text.startswith("front: waypoint"),
          "the front's waypoints", RUN_TIMEOUT_S / 2)
    _wait(browser, lambda d: _by_id(d, "scan").get_attribute("data-scanner") == "front", "the front's scans")
    _wait(browser, lambda d: _by_id(d, "progress-text").text.startswith("rear: waypoint"),
          "the rear's waypoints", RUN_TIMEOUT_S / 2)
    _wait(browser, lambda d: _by_id(d, "scan").get_attribute("data-scanner") == "rear", "the rear's scans")
    _wait(browser, lambda d: _by_id(d, "job-state").text in TERMINAL, "the run's end", RUN_TIMEOUT_S)
    job = _get(cell_daemon, "/v1/jobs")["jobs"][0]
    assert job["state"] == "succeeded", job.get("error")
    # the pair's agreement, told once both scanners are solved, in the page's log
    told = "pair agreement: front and rear: "
    _wait(browser, lambda d: told in _by_id(d, "event-log").get_attribute("textContent"),
          "the pair's agreement in the log")
    ids = job["document"]["calibration_ids"]
    for name in SCANNERS:  # each scanner's result, and its calibration active with its age
        expected = (ids[name], "passed ·", "never verified")
        _wait(browser, lambda d, n=name, parts=expected: all(part in _card(d, n).text for part in parts),
              f"{name}'s active calibration, passed and never verified")
        assert "T_base_laser: t = (" in browser.find_element(
            "css selector", f'#job-result [data-scanner="{name}"]').text

    # The rear chosen: its history alone, its exports in its own frame, its scan picture; verified.
    _click(browser, _card_css("rear"), "the rear's card")
    _wait(browser, lambda d: "laser_rear" in _by_id(d, "exports").text, "the rear's exports")
    rows = browser.find_elements("css selector", "#history-body tr[data-id]")
    assert rows and {row.get_attribute("data-scanner") for row in rows} == {"rear"}
    urdf = browser.find_element("css selector", '[data-export="urdf_joint"]').text
    assert '<child link="laser_rear"/>' in urdf
    assert _by_id(browser, "scan").get_attribute("data-scanner") == "rear"
    assert int(_by_id(browser, "scan").get_attribute("data-scanner-scans")) >= 1
    _by_id(browser, "start-verify").click()
    assert "of rear" in _answer_confirmation(browser, yes=True)
    _wait(browser, lambda d: _get(cell_daemon, "/v1/jobs")["jobs"][0]["kind"] == "verify", "the verify job")
    verify = _get(cell_daemon, "/v1/jobs")["jobs"][0]
    assert verify["request"]["scanner"] == "rear"
    assert verify["request"]["job"] is None and verify["request"]["dwell_s"] is None  # the recorded job's
    _wait(browser, lambda d: f"in use by {verify['id']}" in _card(d, "rear").text,
          "the rear held by the verify")
    assert "in use by" not in _card_text(browser, "front")
    _wait(browser, lambda d: verify["id"] in _by_id(d, "job-title").text
          and _by_id(d, "job-state").text in TERMINAL, "the verify's end", RUN_TIMEOUT_S)
    verdict = _get(cell_daemon, f"/v1/jobs/{verify['id']}")["verdict"]["status"]
    _wait(browser, lambda d: f"verify {verdict}" in _card(d, "rear").text,
          "the rear's verify verdict on its card")
    _wait(browser, lambda d: "in use by" not in _card(d, "rear").text,
          "the rear released at the verify's end", 15)
    assert "never verified" in _card_text(browser, "front")
    _wait(browser, lambda d: d.find_elements("css selector", '#history-body tr[data-kind^="verify"]'),
          "the verify's history row")
    _check_plot_labels(browser)
    _screenshot(browser, artifacts, "cell")

    # Every scanner again: both scanners' rows, each named.
    _click(browser, '#scanner-filter button[data-scanner=""]', "the every-scanner filter")
    _wait(browser, lambda d: {r.get_attribute("data-scanner") for r in d.find_elements(
        "css selector", "#history-body tr[data-id]")} == set(SCANNERS), "every scanner's history")
    assert not _seen(browser, "#exports")
