"""The reference runs (``tests/reference_runs.py``) give the outputs recorded in
``tests/reference/``: byte for byte on a machine of the recorded kind, within each run's
tolerance on another (see the module there)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path
from reference_runs import (
    DIGESTS,
    PLAN_COST,
    RECORDED,
    RUNS,
    SAMPLE_EVERY,
    digest,
    kept_lines,
    machine,
    plan_costs,
)

INDEX = json.loads((RECORDED / "recorded.json").read_text())
SAME_MACHINE = INDEX["machine"] == machine()


def _numbers(lines: list[str]) -> np.ndarray:
    """The numbers of each line (a word that is no number is NaN)."""
    rows = []
    for line in lines:
        values = []
        for f in line.replace(",", " ").split():
            try:
                values.append(float(f))
            except ValueError:
                values.append(float("nan"))
        rows.append(values)
    width = max((len(r) for r in rows), default=0)
    return np.array([r + [np.nan] * (width - len(r)) for r in rows])


def _compare(name: str, file: str, made: Path) -> None:
    recorded = json.loads((RECORDED / name / DIGESTS).read_text())[file]
    if SAME_MACHINE:
        assert digest(made) == recorded, (
            f"{name}/{file} differs from the recorded output on a machine of the recorded kind"
        )
        return
    lines = made.read_text().splitlines()
    assert len(lines) == recorded["lines"], f"{name}/{file}: {len(lines)} lines"
    kept = kept_lines(name, file)
    a = _numbers([lines[i] for i in kept])
    b = _numbers(list(kept.values()))
    assert a.shape == b.shape, f"{name}/{file}: {a.shape} numbers, recorded {b.shape}"
    # Stamps and ids (the first column) are exact; the rest within the run's tolerance.
    np.testing.assert_array_equal(a[:, 0], b[:, 0])
    np.testing.assert_allclose(a[:, 1:], b[:, 1:], rtol=0, atol=RUNS[name].tolerance_m)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(RUNS))
def test_outputs_are_the_recorded_ones(name: str, reference_run) -> None:  # type: ignore[no-untyped-def]
    shared_path()
    run_dir = reference_run(name)
    kept = RECORDED / name
    for file in RUNS[name].files:
        _compare(name, file, run_dir / file)
    if (kept / PLAN_COST).exists():
        recorded = json.loads((kept / PLAN_COST).read_text())
        made = plan_costs(run_dir / "plan.json")
        assert made.keys() == recorded.keys()
        for key, value in recorded.items():
            assert made[key] == pytest.approx(value, abs=1e-9), key


def test_every_reference_run_was_recorded() -> None:
    assert set(INDEX["runs"]) == set(RUNS)
    for name, spec in RUNS.items():
        digests = json.loads((RECORDED / name / DIGESTS).read_text())
        assert set(digests) == set(spec.files)
        for file in spec.files:
            lines = digests[file]["lines"]
            assert len(kept_lines(name, file)) >= max(1, min(lines, lines // SAMPLE_EVERY)), file
