"""Gate evaluation on run.json, the JUnit XML and the self-contained HTML report of a batch."""

from __future__ import annotations

import base64
import copy
import re
import xml.etree.ElementTree as ET
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import pytest

from slamcli.batch.gates import (
    GateResult,
    evaluate_gates,
    flatten_metrics,
    format_value,
    metric_value,
    parse_gate,
)
from slamcli.batch.html import ReportRow, format_change, lower_is_better, write_html_report
from slamcli.batch.junit import JunitCase, write_junit

DENSE_RUN: dict[str, Any] = {
    "metrics": {
        "ms_per_frame": {"extract": 11.9, "integrate": 55.7, "total": 113.4},
        "loop_closures": [],
        "alignment": "se3",
        "evaluation": {
            "alignment": "se3",
            "pairs": 30,
            "ate": {"rmse": 0.0080, "mean": 0.007, "max": 0.02},
            "rpe": {"trans": {"rmse": 0.004}, "rot_deg": {"rmse": 0.3}},
            "scale": 1.0,
        },
    },
    "counts": {
        "frames_read": 30,
        "frames_skipped": 0,
        "frames_lost": 2,
        "keyframes": 3,
        "loop_closures": 1,
    },
}

EKF_RUN: dict[str, Any] = {
    "metrics": {
        "association": "known",
        "nis": {"mean": 2.31},
        "evaluation": {
            "alignment": "se2",
            "matched": 2401,
            "ate": {"rmse": 0.0397},
            "heading_error_deg": {"rmse": 1.5},
            "landmarks": {"rmse_m": 0.036, "matched": 40},
            "degenerate": True,
        },
    },
    "counts": {},
}


# --- metric lookup -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("run", "path", "expected"),
    [
        (DENSE_RUN, "ms_per_frame", 113.4),
        (DENSE_RUN, "ms_per_frame.integrate", 55.7),
        (DENSE_RUN, "ate.rmse", 0.0080),
        (DENSE_RUN, "rpe.trans.rmse", 0.004),
        (DENSE_RUN, "rpe.rot_deg.rmse", 0.3),
        (DENSE_RUN, "evaluation.ate.rmse", 0.0080),
        (DENSE_RUN, "pairs", 30.0),
        (DENSE_RUN, "frames.lost", 2.0),
        (DENSE_RUN, "frames_lost", 2.0),
        (DENSE_RUN, "frames.skipped", 0.0),
        (DENSE_RUN, "loop_closures", 1.0),
        (DENSE_RUN, "loop.closures", 1.0),
        (EKF_RUN, "landmarks.rmse_m", 0.036),
        (EKF_RUN, "heading_error_deg.rmse", 1.5),
        (EKF_RUN, "nis.mean", 2.31),
        (EKF_RUN, "matched", 2401.0),
    ],
)
def test_metric_value_resolves(run: dict[str, Any], path: str, expected: float) -> None:
    value = metric_value(run, path)
    assert isinstance(value, float)
    assert value == pytest.approx(expected)


@pytest.mark.parametrize(
    "path",
    ["ate", "alignment", "degenerate", "ate.nope", "frames.lost", "nope", "rpe.trans", ""],
)
def test_metric_value_absent_or_not_a_number(path: str) -> None:
    assert metric_value(EKF_RUN, path) is None


def test_metric_value_on_broken_run_json() -> None:
    assert metric_value({}, "ate.rmse") is None
    assert metric_value({"metrics": [1], "counts": "x"}, "frames.lost") is None
    assert metric_value({"counts": {"n": 3, "ok": True}}, "n") == 3.0
    assert metric_value({"counts": {"n": 3, "ok": True}}, "ok") is None


def test_evaluation_shadows_metrics() -> None:
    run = {"metrics": {"scale": 2.0, "evaluation": {"scale": 1.0}}}
    assert metric_value(run, "scale") == 1.0


def test_flatten_metrics_names_agree_with_metric_value() -> None:
    flat = flatten_metrics(DENSE_RUN)
    assert flat["ate.rmse"] == 0.0080
    assert flat["ms_per_frame"] == 113.4
    assert flat["ms_per_frame.total"] == 113.4
    assert flat["frames_lost"] == flat["frames.lost"] == 2.0
    assert flat["rpe.rot_deg.rmse"] == 0.3
    assert not any(name.startswith("evaluation.") for name in flat)
    assert "alignment" not in flat and "loop_closures" in flat
    for name, value in flat.items():
        assert metric_value(DENSE_RUN, name) == value
    ekf = flatten_metrics(EKF_RUN)
    assert ekf["landmarks.rmse_m"] == 0.036
    assert "degenerate" not in ekf
    assert flatten_metrics({}) == {}


# --- gate evaluation -----------------------------------------------------------------------


def _one(text: str, run: dict[str, Any], baseline: dict[str, Any] | None = None) -> GateResult:
    (result,) = evaluate_gates([parse_gate(text)], run, baseline)
    return result


@pytest.mark.parametrize(
    ("text", "failed"),
    [
        ("ate.rmse > 0.03", False),
        ("ate.rmse > 0.005", True),
        ("ate.rmse >= 0.008", True),
        ("ate.rmse < 0.008", False),
        ("ate.rmse <= 0.008", True),
        ("frames.lost > 0", True),
        ("frames.lost == 2", True),
        ("frames.lost != 2", False),
        ("keyframes < 5", True),
    ],
)
def test_gate_condition_is_the_failure_condition(text: str, failed: bool) -> None:
    result = _one(text, DENSE_RUN)
    assert result.failed is failed
    assert result.limit == parse_gate(text).threshold
    assert result.gate == text


def test_failed_gate_reason_shows_value_and_limit() -> None:
    run = copy.deepcopy(DENSE_RUN)
    run["metrics"]["evaluation"]["ate"]["rmse"] = 0.0312
    result = _one("ate.rmse > 0.03", run)
    assert result.failed
    assert result.reason == "ate.rmse = 0.0312 > 0.03"
    assert result.value == 0.0312
    assert _one("ate.rmse > 0.04", run).reason == "ate.rmse = 0.0312, not > 0.04"


def test_reason_never_prints_unequal_numbers_alike() -> None:
    run = {"metrics": {"evaluation": {"ate": {"rmse": 0.0300001}}}}
    reason = _one("ate.rmse > 0.03", run).reason
    assert reason == "ate.rmse = 0.0300001 > 0.03"


def test_missing_metric_fails_with_reason() -> None:
    result = _one("landmarks.rmse_m > 1", DENSE_RUN)
    assert result.failed
    assert result.value is None and result.limit is None
    assert result.reason == "landmarks.rmse_m is missing from run.json"


def test_nan_metric_fails() -> None:
    result = _one("ate.rmse > 1", {"metrics": {"evaluation": {"ate": {"rmse": float("nan")}}}})
    assert result.failed and "NaN" in result.reason


def test_baseline_gate() -> None:
    baseline = copy.deepcopy(DENSE_RUN)
    baseline["metrics"]["ms_per_frame"]["total"] = 100.0
    slow = _one("ms_per_frame > 1.1 * baseline", DENSE_RUN, baseline)
    assert slow.failed
    assert slow.limit == pytest.approx(110.0)
    assert slow.baseline == 100.0
    assert slow.reason == "ms_per_frame = 113.4 > 110 (1.1 × baseline 100)"
    ok = _one("ms_per_frame > 1.2 * baseline", DENSE_RUN, baseline)
    assert not ok.failed
    assert ok.limit == pytest.approx(120.0)
    same = _one("ate.rmse > baseline", DENSE_RUN, DENSE_RUN)
    assert not same.failed and same.limit == 0.0080


def test_baseline_gate_without_baseline_fails() -> None:
    no_run = _one("ate.rmse > 1.1 * baseline", DENSE_RUN)
    assert no_run.failed
    assert no_run.reason == "no baseline value for ate.rmse (no baseline run given)"
    no_value = _one("ate.rmse > 1.1 * baseline", DENSE_RUN, {"metrics": {}})
    assert no_value.failed
    assert no_value.reason == "no baseline value for ate.rmse"
    assert no_value.value == 0.0080


def test_evaluate_keeps_order_and_count() -> None:
    gates = [parse_gate(t) for t in ("frames.lost > 0", "ate.rmse > 1", "nope > 1")]
    results = evaluate_gates(gates, DENSE_RUN)
    assert [r.metric for r in results] == ["frames.lost", "ate.rmse", "nope"]
    assert [r.failed for r in results] == [True, False, True]


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (None, "—"),
        (30.0, "30"),
        (0.0312, "0.0312"),
        (113.4, "113.4"),
        (12345.67, "12345.7"),
        (1.23456e-5, "1.23e-05"),
        (-0.5, "-0.5"),
    ],
)
def test_format_value(value: float | None, text: str) -> None:
    assert format_value(value) == text


# --- JUnit ---------------------------------------------------------------------------------


def _cases() -> list[JunitCase]:
    return [
        JunitCase("dense-a", "dense", 12.3456, "passed", properties={"ate.rmse": "0.008"}),
        JunitCase(
            "visual-rpy",
            "visual",
            40.0,
            "gate_failed",
            message="1 of 2 gates failed",
            details="✗ ate.rmse = 0.0312 > 0.03\n✓ frames.lost = 0, not > 0",
        ),
        JunitCase("ekf-1", "ekf", 3.0, "data_lost", message="5 frames lost", details="lost"),
        JunitCase(
            "broken",
            "dense",
            0.5,
            "error",
            message="run.json missing",
            details="Traceback\x1b[31m red\x00\n  boom",
            stdout="log line <with> & markup",
        ),
    ]


def test_junit_counts_and_structure(tmp_path: Path) -> None:
    path = write_junit(tmp_path / "junit.xml", "slamcli batch", _cases())
    assert path == tmp_path / "junit.xml"
    assert list(tmp_path.iterdir()) == [path]
    root = ET.parse(path).getroot()
    assert root.tag == "testsuites"
    (suite,) = list(root)
    assert suite.tag == "testsuite"
    for element in (root, suite):
        assert element.get("tests") == "4"
        assert element.get("failures") == "2"
        assert element.get("errors") == "1"
        assert element.get("name") == "slamcli batch"
        assert float(element.get("time", "nan")) == pytest.approx(55.846, abs=1e-3)
    cases = suite.findall("testcase")
    assert [c.get("name") for c in cases] == ["dense-a", "visual-rpy", "ekf-1", "broken"]
    assert [c.get("classname") for c in cases] == ["dense", "visual", "ekf", "dense"]
    assert cases[0].get("time") == "12.346"
    for case in cases:
        assert set(case.keys()) >= {"name", "classname", "time"}
        assert all(child.tag in ("properties", "failure", "error", "system-out") for child in case)

    passed, gate_failed, data_lost, error = cases
    assert passed.find("failure") is None and passed.find("error") is None
    prop = passed.find("properties/property")
    assert prop is not None and prop.attrib == {"name": "ate.rmse", "value": "0.008"}

    failure = gate_failed.find("failure")
    assert failure is not None
    assert failure.get("type") == "gate_failed"
    assert failure.get("message") == "1 of 2 gates failed"
    assert failure.text == "✗ ate.rmse = 0.0312 > 0.03\n✓ frames.lost = 0, not > 0"

    lost = data_lost.find("failure")
    assert lost is not None and lost.get("type") == "data_lost"

    assert error.find("failure") is None
    err = error.find("error")
    assert err is not None and err.get("type") == "error"
    assert err.text == "Traceback[31m red\n  boom"
    out = error.find("system-out")
    assert out is not None and out.text == "log line <with> & markup"


def test_junit_empty_batch_and_timestamp(tmp_path: Path) -> None:
    path = write_junit(tmp_path / "j.xml", "empty", [], timestamp="2026-01-02T03:04:05")
    root = ET.parse(path).getroot()
    suite = root.find("testsuite")
    assert suite is not None
    assert suite.get("tests") == "0" and suite.get("timestamp") == "2026-01-02T03:04:05"
    assert root.get("timestamp") is None


def test_junit_is_deterministic(tmp_path: Path) -> None:
    a = write_junit(tmp_path / "a.xml", "s", _cases()).read_bytes()
    b = write_junit(tmp_path / "b.xml", "s", _cases()).read_bytes()
    assert a == b
    assert a.startswith(b'<?xml version="1.0" encoding="UTF-8"?>')


def test_junit_rejects_unknown_status() -> None:
    with pytest.raises(ValueError, match="status must be one of"):
        JunitCase("x", "dense", 1.0, "failed")


# --- HTML ----------------------------------------------------------------------------------

PNG = base64.b64decode(
    "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mP8z8DwHwAFBQIAX8jx0gAAAABJRU5ErkJggg=="
)


class _Links(HTMLParser):
    """Collects every src/href value and the tags seen."""

    def __init__(self) -> None:
        super().__init__()
        self.urls: list[str] = []
        self.tags: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append(tag)
        self.urls += [v or "" for k, v in attrs if k in ("src", "href")]


def _rows(tmp_path: Path) -> list[ReportRow]:
    png = tmp_path / "report.png"
    png.write_bytes(PNG)
    gates = evaluate_gates(
        [parse_gate("ate.rmse > 0.03"), parse_gate("frames.lost > 0")], DENSE_RUN
    )
    return [
        ReportRow(
            name="dense-<script>alert(1)</script>",
            pipeline="dense",
            input="data/rgbd & co",
            status="gate_failed",
            wall_s=75.0,
            gates=gates,
            metrics={"ate.rmse": 0.0312, "ms_per_frame": 113.4},
            changes={"ate.rmse": (0.03253, 0.0312), "ms_per_frame": (100.0, 113.4)},
            run_link="dense-x/",
            report_png=png,
        ),
        ReportRow(
            name="ekf-1",
            pipeline="ekf",
            input="run.mcap",
            status="passed",
            wall_s=3.25,
            metrics={"matched": 2401.0},
            changes={"matched": (2400.0, 2401.0)},
            run_link="ekf-1/",
        ),
        ReportRow(
            name="broken",
            pipeline="visual",
            input="x",
            status="error",
            wall_s=0.1,
            error='Traceback <module>\n  ValueError: "bad" & worse',
            report_png=tmp_path / "absent.png",
        ),
    ]


def _report(tmp_path: Path, **kwargs: Any) -> str:
    path = write_html_report(
        tmp_path / "report.html",
        kwargs.pop("title", "Nightly <batch>"),
        kwargs.pop("rows", _rows(tmp_path)),
        baseline_label=kwargs.pop("baseline_label", "main@1234"),
        generated="2026-01-02 03:04",
    )
    return path.read_text(encoding="utf-8")


def test_report_is_self_contained(tmp_path: Path) -> None:
    text = _report(tmp_path)
    assert "http://" not in text and "https://" not in text
    parser = _Links()
    parser.feed(text)
    assert "script" not in parser.tags
    images = [u for u in parser.urls if u.startswith("data:")]
    assert len(images) == 1
    assert images[0] == "data:image/png;base64," + base64.b64encode(PNG).decode()
    for url in parser.urls:
        assert not re.match(r"^[a-z]+:", url) or url.startswith("data:image/"), url
    assert set(parser.urls) - set(images) == {"#job-1", "#job-2", "#job-3", "dense-x/", "ekf-1/"}
    assert "<style>" in text and "max-width: 100%" in text


def test_report_escapes_text(tmp_path: Path) -> None:
    text = _report(tmp_path)
    assert "<script>" not in text
    assert "dense-&lt;script&gt;alert(1)&lt;/script&gt;" in text
    assert "<title>Nightly &lt;batch&gt;</title>" in text
    assert "data/rgbd &amp; co" in text
    assert "<pre>Traceback &lt;module&gt;\n  ValueError: &quot;bad&quot; &amp; worse</pre>" in text


def test_report_status_counts(tmp_path: Path) -> None:
    text = _report(tmp_path)
    counts = dict(
        re.findall(r'<span><span class="badge status-(\w+)">[^<]*</span> (\d+)</span>', text)
    )
    assert counts == {"passed": "1", "gate_failed": "1", "data_lost": "0", "error": "1"}
    assert "Generated 2026-01-02 03:04 · 3 jobs" in text
    assert "main@1234" in text


def test_report_changes_show_percentages_and_direction(tmp_path: Path) -> None:
    text = _report(tmp_path)
    assert '<span class="better">0.0312 (−4.1 %)</span>' in text
    assert '<span class="worse">113.4 (+13.4 %)</span>' in text
    assert '<span class="neutral">2401 (+0.0 %)</span>' in text
    assert "Change against baseline" in text


def test_report_gates_and_missing_image(tmp_path: Path) -> None:
    text = _report(tmp_path)
    assert "✓</span> <code>ate.rmse &gt; 0.03</code>: ate.rmse = 0.008, not &gt; 0.03" in text
    assert "✗</span> <code>frames.lost &gt; 0</code>: frames.lost = 2 &gt; 0" in text
    assert "report image not available" in text and "absent.png" in text


def test_report_without_baseline_has_no_change_column(tmp_path: Path) -> None:
    rows = [ReportRow("a", "dense", "x", "passed", 1.0, metrics={"ate.rmse": 0.01})]
    text = _report(tmp_path, rows=rows, baseline_label=None)
    assert "Change against baseline" not in text
    assert "compared with baseline" not in text


def test_report_is_deterministic_and_atomic(tmp_path: Path) -> None:
    first = _report(tmp_path)
    assert _report(tmp_path) == first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.html", "report.png"]


@pytest.mark.parametrize(
    ("metric", "baseline", "now", "text", "css"),
    [
        ("ate.rmse", 0.03253, 0.0312, "0.0312 (−4.1 %)", "better"),
        ("rpe.trans.rmse", 1.0, 1.5, "1.5 (+50.0 %)", "worse"),
        ("frames.lost", 0.0, 2.0, "2 (+2, baseline 0)", "worse"),
        ("heading_error_deg.rmse", 2.0, 1.0, "1 (−50.0 %)", "better"),
        ("keyframes", 4.0, 2.0, "2 (−50.0 %)", "neutral"),
        ("ate.rmse", 0.01, 0.01, "0.01 (±0 %)", "neutral"),
        ("ate.rmse", None, 0.01, "0.01 (new)", "neutral"),
        ("ate.rmse", 0.01, None, "missing (baseline 0.01)", "worse"),
    ],
)
def test_format_change(
    metric: str, baseline: float | None, now: float | None, text: str, css: str
) -> None:
    assert format_change(metric, baseline, now) == (text, css)


@pytest.mark.parametrize(
    ("metric", "lower"),
    [
        ("ate.rmse", True),
        ("ms_per_frame", True),
        ("ms_per_frame.integrate", True),
        ("frames_lost", True),
        ("landmarks.rmse_m", True),
        ("keyframes", False),
        ("matched", False),
        ("rate", False),
    ],
)
def test_lower_is_better(metric: str, lower: bool) -> None:
    assert lower_is_better(metric) is lower
