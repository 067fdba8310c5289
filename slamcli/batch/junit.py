"""JUnit XML for a batch, so CI servers (Jenkins, GitLab, GitHub annotators) show one test per job.

The layout is the common denominator those tools read: a ``<testsuites>`` root holding one
``<testsuite>`` with ``<testcase name classname time>`` children. A failed gate or lost data is
a ``<failure>``, anything else that went wrong an ``<error>``.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from slamcli.atomic import write_text_atomic

STATUSES = ("passed", "gate_failed", "data_lost", "error")
"""The outcomes a job can have, as written in reports."""

_NOT_XML = re.compile("[^\t\n\r\u0020-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")


@dataclass
class JunitCase:
    """One job as a test case; ``properties`` are shown by CI tools as key/value pairs."""

    name: str
    classname: str
    time_s: float
    status: str
    message: str = ""
    details: str = ""
    properties: Mapping[str, str] = field(default_factory=dict)
    stdout: str = ""

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status must be one of {', '.join(STATUSES)}, not {self.status!r}")


def _clean(text: str) -> str:
    """Drop characters XML 1.0 cannot hold (terminal escapes, NULs in tracebacks)."""
    return _NOT_XML.sub("", text)


def _seconds(t: float) -> str:
    return f"{max(t, 0.0):.3f}"


def junit_xml(suite_name: str, cases: Sequence[JunitCase], *, timestamp: str | None = None) -> str:
    """The JUnit XML document for ``cases``, as text."""
    failures = sum(c.status in ("gate_failed", "data_lost") for c in cases)
    errors = sum(c.status == "error" for c in cases)
    total = _seconds(sum(c.time_s for c in cases))
    counts = {
        "tests": str(len(cases)),
        "failures": str(failures),
        "errors": str(errors),
        "skipped": "0",
        "time": total,
    }
    root = ET.Element("testsuites", {"name": _clean(suite_name), **counts})
    suite_attrs = {"name": _clean(suite_name), **counts}
    if timestamp is not None:
        suite_attrs["timestamp"] = timestamp
    suite = ET.SubElement(root, "testsuite", suite_attrs)
    for case in cases:
        tc = ET.SubElement(
            suite,
            "testcase",
            {
                "name": _clean(case.name),
                "classname": _clean(case.classname),
                "time": _seconds(case.time_s),
            },
        )
        if case.properties:
            props = ET.SubElement(tc, "properties")
            for key, value in case.properties.items():
                ET.SubElement(props, "property", {"name": _clean(key), "value": _clean(value)})
        if case.status != "passed":
            tag = "error" if case.status == "error" else "failure"
            outcome = ET.SubElement(tc, tag, {"message": _clean(case.message), "type": case.status})
            outcome.text = _clean(case.details)
        if case.stdout:
            ET.SubElement(tc, "system-out").text = _clean(case.stdout)
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def write_junit(
    path: str | Path,
    suite_name: str,
    cases: Sequence[JunitCase],
    *,
    timestamp: str | None = None,
) -> Path:
    """Write the JUnit XML for ``cases`` to ``path`` atomically; returns the path.

    ``timestamp`` (ISO 8601), when given, is set on the ``<testsuite>``; without it the file
    depends only on the cases.
    """
    return write_text_atomic(path, junit_xml(suite_name, cases, timestamp=timestamp))
