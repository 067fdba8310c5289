"""Landmark sources: MRCLAM folders, Victoria Park files and 'slamcli synth landmarks' folders."""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import pytest
import typer
from click.testing import Result
from conftest import shared_path
from typer.testing import CliRunner

from slamcli.cli import info as info_cmd
from slamcli.errors import ConfigError, FormatError, InputError, UnknownFormatError
from slamcli.formats import SOURCES, open_source, source_class
from slamcli.formats.landmarks import (
    START_POSE_MAX_WAIT_S,
    VICTORIA_STEP_NS,
    LandmarkSource,
    LandmarkWorldSource,
    MrclamSource,
    VictoriaParkSource,
    read_table,
)
from slamcli.formats.text import parse_stamp_ns
from slamcli.formats.tum_rgbd import TumRgbdSource
from slamcli.types import LandmarkFrame, OdometryFrame

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "landmarks"
"""The sample landmark world (``slamcli synth landmarks``, seed 0)."""
ROBOT_SUBJECTS = {1, 2, 3, 4, 5}
runner = CliRunner()


# --- helpers ----------------------------------------------------------------------------------


def mrclam() -> Path:
    return shared_path("landmarks", "MRCLAM_Dataset6")


def victoria() -> Path:
    return shared_path("landmarks", "victoria_park.txt")


def data_rows(path: Path) -> list[tuple[int, list[str]]]:
    """(1-based line, fields) of every non-comment line, parsed the simple way."""
    rows = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if line.strip() and not line.strip().startswith("#"):
            rows.append((number, line.split()))
    return rows


def barcode_subjects(folder: Path) -> dict[int, int]:
    return {int(b): int(s) for _, (s, b) in data_rows(folder / "Barcodes.dat")}


def landmark_subjects(folder: Path) -> set[int]:
    return {int(f[0]) for _, f in data_rows(folder / "Landmark_Groundtruth.dat")}


def split(frames: Iterable[object]) -> tuple[list[OdometryFrame], list[LandmarkFrame]]:
    odo, obs = [], []
    for f in frames:
        (odo if isinstance(f, OdometryFrame) else obs).append(f)
    return odo, obs  # type: ignore[return-value]


_MRCLAM_HEADER = (
    "# UTIAS Multi-Robot Cooperative Localization and Mapping Dataset\n"
    "# produced by a test\n"
    "# {what} Data Format:\n"
    "# {columns}\n"
)


def write_mrclam(
    folder: Path,
    odometry: list[str] | None = None,
    measurements: list[str] | None = None,
    groundtruth: list[str] | None = None,
    robots: Iterable[int] = (1,),
) -> Path:
    """A tiny MRCLAM folder; every data file has 4 comment lines, so row k is on line k + 4."""
    folder.mkdir(parents=True, exist_ok=True)

    def write(name: str, what: str, columns: str, lines: list[str]) -> None:
        text = _MRCLAM_HEADER.format(what=what, columns=columns) + "".join(
            line + "\n" for line in lines
        )
        (folder / name).write_text(text)

    # Subjects 1-5 are robots (barcodes 5, 14, 41, 32, 23), 6-8 landmarks (63, 81, 7).
    write(
        "Barcodes.dat",
        "Barcode",
        "Subject #    Barcode #",
        [
            f"  {s} \t  {b}"
            for s, b in [(1, 5), (2, 14), (3, 41), (4, 32), (5, 23), (6, 63), (7, 81), (8, 7)]
        ],
    )
    write(
        "Landmark_Groundtruth.dat",
        "Landmark Groundtruth",
        "Subject #    x [m]    y [m]    x std-dev [m]    y std-dev [m]",
        [
            "  6 \t 1.0 \t 2.0 \t 0.01 \t 0.02",
            "  7 \t -1.0 \t 3.0 \t 0.03 \t 0.04",
            "  8 \t 0.5 \t -2.0 \t 0.05 \t 0.06",
        ],
    )
    odometry = odometry or [
        "100.000 \t 0.1 \t 0.0",
        "100.500 \t 0.2 \t 0.1",
        "100.500 \t 0.3 \t 0.2",
        "101.000 \t 0.4 \t 0.3",
        "102.400 \t 0.5 \t 0.4",
    ]
    measurements = measurements or [
        "100.500 \t 63 \t 2.0 \t 0.5",
        "100.500 \t 14 \t 3.0 \t -0.5",
        "100.500 \t 81 \t 4.0 \t 0.25",
        "100.700 \t 43 \t 5.0 \t 0.0",
        "101.000 \t 7 \t 6.0 \t 1.0",
    ]
    groundtruth = groundtruth or [
        "99.000 \t 0.0 \t 0.0 \t 0.0",
        "101.000 \t 2.0 \t 1.0 \t 1.0",
        "101.000 \t 9.0 \t 9.0 \t 9.0",
        "103.000 \t 4.0 \t 2.0 \t 2.0",
    ]
    for r in robots:
        write(f"Robot{r}_Odometry.dat", "Odometry", "Time [s]  v [m/s]  w [rad/s]", odometry)
        write(f"Robot{r}_Measurement.dat", "Measurement", "Time [s]  Subject #  r  b", measurements)
        write(f"Robot{r}_Groundtruth.dat", "Robot Groundtruth", "Time [s] x y th", groundtruth)
    return folder


def write_world(folder: Path, odometry: list[str], measurements: list[str]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "odometry.csv").write_text("t,v,omega\n" + "".join(x + "\n" for x in odometry))
    (folder / "measurements.csv").write_text(
        "t,id,range,bearing\n" + "".join(x + "\n" for x in measurements)
    )
    return folder


def _app() -> typer.Typer:
    app = typer.Typer(pretty_exceptions_enable=False)

    @app.callback()
    def _root() -> None:
        """Root with a callback, so ``info`` stays a subcommand as in the real app."""

    info_cmd.register(app)
    return app


def invoke(*args: str | Path) -> Result:
    return runner.invoke(_app(), ["info", *map(str, args)])


def check_order(frames: list[object]) -> None:
    """Stamps never decrease, and at one stamp no odometry frame follows a landmark frame."""
    keys = [(f.stamp_ns, isinstance(f, LandmarkFrame)) for f in frames]  # type: ignore[attr-defined]
    assert keys == sorted(keys)


# --- MRCLAM, real data ------------------------------------------------------------------------


@pytest.mark.parametrize("robot", [1, 2, 3, 4, 5])
def test_mrclam_counts_match_the_files(robot: int) -> None:
    folder = mrclam()
    codes = barcode_subjects(folder)
    landmarks = landmark_subjects(folder)
    odo_rows = data_rows(folder / f"Robot{robot}_Odometry.dat")
    meas_rows = data_rows(folder / f"Robot{robot}_Measurement.dat")
    subjects = [codes.get(int(f[1])) for _, f in meas_rows]
    sightings = sum(s in ROBOT_SUBJECTS for s in subjects)
    unknown = sum(s is None for s in subjects)
    kept = [(n, f) for (n, f), s in zip(meas_rows, subjects, strict=True) if s in landmarks]
    assert len(kept) == len(meas_rows) - sightings - unknown

    with MrclamSource(folder, robot=robot) as src:
        odo, obs = split(src.frames())
        info = src.info()
        assert len(odo) == len(odo_rows)
        assert sum(f.ids.size for f in obs) == len(kept)
        assert len(obs) == len({n_f[1][0] for n_f in kept})
        assert info.details["robot_sightings"] == sightings > 0
        assert sum(info.details["unknown_barcodes"].values()) == unknown == len(src.ignored)
        assert info.frames == len(odo) + len(obs)
        assert src.stats.read == info.frames
        counts = {s.name: s.count for s in info.streams}
        assert counts[f"Robot{robot}_Odometry.dat"] == len(odo_rows)
        assert counts[f"Robot{robot}_Measurement.dat"] == len(meas_rows)
        assert info.groundtruth == len(src.groundtruth() or ())
        # Exact stamps and values, row by row.
        assert [f.stamp_ns for f in odo] == [parse_stamp_ns(f[0], "x", n) for n, f in odo_rows]
        assert [f.v for f in odo] == [float(f[1]) for _, f in odo_rows]
        assert [f.omega for f in odo] == [float(f[2]) for _, f in odo_rows]
        ranges = np.concatenate([f.ranges_m for f in obs])
        assert np.array_equal(ranges, [float(f[2]) for _, f in kept])


def test_mrclam_frames_are_ordered_and_ids_are_landmarks() -> None:
    folder = mrclam()
    truth_ids = landmark_subjects(folder)
    with MrclamSource(folder, robot=3) as src:
        frames = list(src.frames())
        check_order(frames)
        odo, obs = split(frames)
        ids = set(np.concatenate([f.ids for f in obs]).tolist())
        truth = src.landmark_truth()
    assert truth is not None and set(truth.ids.tolist()) == truth_ids == set(range(6, 21))
    assert ids <= truth_ids and not ids & ROBOT_SUBJECTS
    # Robot 3 has repeated odometry stamps: they are all kept, in file order.
    stamps = np.array([f.stamp_ns for f in odo])
    assert np.count_nonzero(np.diff(stamps) == 0) == 8
    # Ties between odometry and measurements exist and put odometry first.
    odo_stamps = set(stamps.tolist())
    assert any(f.stamp_ns in odo_stamps for f in obs)
    assert truth.cov is not None
    first = data_rows(folder / "Landmark_Groundtruth.dat")[0][1]
    assert truth.cov[0, 0, 0] == pytest.approx(float(first[3]) ** 2)
    assert truth.cov[0, 1, 1] == pytest.approx(float(first[4]) ** 2)
    assert truth.xy[0].tolist() == [float(first[1]), float(first[2])]


def test_mrclam_unknown_barcodes_are_skipped_and_counted(caplog: pytest.LogCaptureFixture) -> None:
    folder = mrclam()
    path = folder / "Robot1_Measurement.dat"
    line = next(n for n, f in data_rows(path) if f[1] == "43")
    src = MrclamSource(folder, robot=1)
    assert src.stats.skipped == 0
    with caplog.at_level("WARNING"):
        list(src.frames(("landmarks",)))
    assert src.stats.skipped == 0  # ignored, not lost: no exit code 3
    assert src.ignored == [f"Robot1_Measurement.dat:{line} barcode 43"]
    assert len([r for r in caplog.records if "43 (1x)" in r.getMessage()]) == 1
    info = src.info()
    assert info.details["unknown_barcodes"] == {"43": 1}
    assert any("43" in p for p in info.problems)
    with pytest.raises(
        FormatError, match=rf"Robot1_Measurement.dat:{line}: barcode 43 is not in"
    ) as e:
        MrclamSource(folder, robot=1, strict=True)
    assert e.value.line == line and e.value.hint


def test_mrclam_ignore_ids() -> None:
    with MrclamSource(mrclam(), robot=2, ignore_ids=True) as src:
        _, obs = split(src.frames(("landmarks",)))
    ids = np.concatenate([f.ids for f in obs])
    assert ids.size > 1000 and np.all(ids == -1) and ids.dtype == np.int64


def test_mrclam_unknown_robot_lists_the_robots() -> None:
    folder = mrclam()
    with pytest.raises(InputError, match=r"no robot 9 .*robots: 1, 2, 3, 4, 5") as e:
        open_source(folder, robot=9)
    assert str(folder) in str(e.value)
    assert e.value.exit_code == 1


def test_mrclam_groundtruth_and_start_pose() -> None:
    folder = mrclam()
    with MrclamSource(folder, robot=1) as src:
        gt = src.groundtruth()
        first = next(iter(src.frames()))
        start = src.start_pose()
        info = src.info()
    assert gt is not None and np.all(np.diff(gt.stamps_ns) > 0)
    assert np.allclose(gt.world_from_body[:, 2, 3], 0.0)
    odo_rows = data_rows(folder / "Robot1_Odometry.dat")
    assert first.stamp_ns == parse_stamp_ns(odo_rows[0][1][0], "x", 1)
    # Robot 1's ground truth starts before its odometry: interpolate the two rows around it.
    rows = data_rows(folder / "Robot1_Groundtruth.dat")
    t = np.array([parse_stamp_ns(f[0], "x", n) for n, f in rows])
    assert t[0] < first.stamp_ns
    k = int(np.searchsorted(t, first.stamp_ns))
    a, b = np.array(rows[k - 1][1], float), np.array(rows[k][1], float)
    w = (first.stamp_ns - t[k - 1]) / (t[k] - t[k - 1])
    expected = a[1:] + w * (b[1:] - a[1:])
    assert start is not None and start.shape == (3,)
    assert np.allclose(start, expected, atol=1e-9)
    # Its ground truth ends ~128 s before the odometry: reported, not invented.
    assert gt.stamps_ns[-1] == t[-1]
    assert any("ground truth ends 128" in p for p in info.problems)


def test_mrclam_copied_folder_with_a_bad_measurement_line(tmp_path: Path) -> None:
    src_folder = mrclam()
    folder = tmp_path / "MRCLAM_copy"
    folder.mkdir()
    for name in ("Barcodes.dat", "Landmark_Groundtruth.dat", "Robot2_Odometry.dat"):
        shutil.copy(src_folder / name, folder / name)
    lines = (src_folder / "Robot2_Measurement.dat").read_text().splitlines(keepends=True)
    lines[99] = "1248444300.123 \t 63 \t abc \t 0.1\n"  # line 100
    (folder / "Robot2_Measurement.dat").write_text("".join(lines))
    with pytest.raises(FormatError, match=r"Robot2_Measurement.dat:100: column 3: .*'abc'") as e:
        open_source(folder, robot=2)
    assert e.value.line == 100
    lines[99] = "1248444300.123 \t 63 \t 2.0\n"
    (folder / "Robot2_Measurement.dat").write_text("".join(lines))
    with pytest.raises(FormatError, match=r"Robot2_Measurement.dat:100: expected 4 fields"):
        open_source(folder, robot=2)


# --- MRCLAM, small written folders ------------------------------------------------------------


def test_small_mrclam_folder_frames(tmp_path: Path) -> None:
    folder = write_mrclam(tmp_path / "m")
    with open_source(folder) as src:
        assert isinstance(src, MrclamSource)
        frames = list(src.frames())
        info = src.info()
    check_order(frames)
    kinds = [(type(f).__name__, f.stamp_ns) for f in frames]
    s = 1_000_000_000
    assert kinds == [
        ("OdometryFrame", 100 * s),
        ("OdometryFrame", 100 * s + 500_000_000),
        ("OdometryFrame", 100 * s + 500_000_000),
        ("LandmarkFrame", 100 * s + 500_000_000),
        ("OdometryFrame", 101 * s),
        ("LandmarkFrame", 101 * s),
        ("OdometryFrame", 102 * s + 400_000_000),
    ]
    assert [frames[1].v, frames[2].v] == [0.2, 0.3]  # repeated stamps keep file order
    lm = frames[3]
    assert isinstance(lm, LandmarkFrame)
    assert lm.ids.tolist() == [6, 7] and lm.ranges_m.tolist() == [2.0, 4.0]
    assert lm.bearings_rad.tolist() == [0.5, 0.25]
    assert info.details["robot_sightings"] == 1
    assert info.details["unknown_barcodes"] == {"43": 1}
    assert info.details["odometry_repeated_stamps"] == 1
    assert info.details["odometry_max_gap_s"] == pytest.approx(1.4)
    assert src.ignored == ["Robot1_Measurement.dat:8 barcode 43"]


def test_small_mrclam_kinds(tmp_path: Path) -> None:
    src = MrclamSource(write_mrclam(tmp_path / "m"))
    assert all(isinstance(f, OdometryFrame) for f in src.frames(("odometry",)))
    assert len(list(src.frames(("odometry",)))) == 5
    assert len(list(src.frames(["landmarks"]))) == 2
    assert src.ignored == ["Robot1_Measurement.dat:8 barcode 43"]
    with pytest.raises(ConfigError, match="no rgbd frames") as e:
        src.frames(("rgbd", "odometry"))
    assert e.value.hint is not None and "odometry, landmarks" in e.value.hint


def test_small_mrclam_groundtruth_drops_repeated_stamps(tmp_path: Path) -> None:
    src = MrclamSource(write_mrclam(tmp_path / "m"))
    gt = src.groundtruth()
    assert gt is not None and len(gt) == 3
    assert gt.positions[1].tolist() == [2.0, 1.0, 0.0]  # the first row of the repeated stamp
    # start at 100.0 s: halfway from (0, 0, 0) at 99 s to (2, 1, 1) at 101 s
    start = src.start_pose()
    assert start is not None and np.allclose(start, [1.0, 0.5, 0.5])


def test_odometry_time_backwards(tmp_path: Path) -> None:
    odo = ["100.000 0.1 0.0", "100.500 0.2 0.1", "100.400 0.3 0.2", "101.000 0.4 0.3"]
    folder = write_mrclam(tmp_path / "m", odometry=odo)
    with pytest.raises(
        FormatError, match=r"Robot1_Odometry.dat:7: time goes backwards from 100.5 to 100.4"
    ):
        MrclamSource(folder)


def test_measurement_time_backwards(tmp_path: Path) -> None:
    meas = ["100.500 63 2.0 0.5", "100.200 81 4.0 0.25"]
    folder = write_mrclam(tmp_path / "m", measurements=meas)
    with pytest.raises(FormatError, match=r"Robot1_Measurement.dat:6: time goes backwards"):
        MrclamSource(folder)


@pytest.mark.parametrize(
    ("bad", "match"),
    [
        ("100.600 0.2", r"Robot1_Odometry.dat:6: expected 3 fields \(time, v, omega\), found 2"),
        ("100.600 0.2 x", r"Robot1_Odometry.dat:6: column 3: value 'x' is not a number"),
        ("100.600 0.2 nan", r"Robot1_Odometry.dat:6: column 3: value 'nan' is not finite"),
        ("1e2x 0.2 0.1", r"Robot1_Odometry.dat:6: timestamp '1e2x' is not a number"),
    ],
)
def test_bad_odometry_lines(tmp_path: Path, bad: str, match: str) -> None:
    folder = write_mrclam(tmp_path / "m", odometry=["100.000 0.1 0.0", bad, "101.000 0.4 0.3"])
    with pytest.raises(FormatError, match=match):
        MrclamSource(folder)


def test_non_integer_barcode(tmp_path: Path) -> None:
    folder = write_mrclam(tmp_path / "m", measurements=["100.5 63 2.0 0.5", "100.6 63.5 2.0 0.5"])
    with pytest.raises(FormatError, match=r"Robot1_Measurement.dat:6: barcode 63.5 is not an"):
        MrclamSource(folder)


def test_start_pose_fallback(tmp_path: Path) -> None:
    late = ["105.000 1.0 2.0 0.3", "106.000 1.5 2.0 0.3"]
    src = MrclamSource(write_mrclam(tmp_path / "a", groundtruth=late))
    start = src.start_pose()
    assert start is not None and np.allclose(start, [1.0, 2.0, 0.3])  # 5 s late: its first pose
    gap = START_POSE_MAX_WAIT_S + 10
    too_late = [f"{100 + gap:.3f} 1.0 2.0 0.3", f"{101 + gap:.3f} 1.5 2.0 0.3"]
    assert MrclamSource(write_mrclam(tmp_path / "b", groundtruth=too_late)).start_pose() is None
    early = ["90.000 1.0 2.0 0.3", "95.000 1.5 2.0 0.3"]
    src = MrclamSource(write_mrclam(tmp_path / "c", groundtruth=early))
    assert src.start_pose() is None
    assert any("ground truth ends" in p for p in src.info().problems)


def test_robot_option_and_missing_files(tmp_path: Path) -> None:
    folder = write_mrclam(tmp_path / "m", robots=(2, 4))
    assert MrclamSource(folder, robot=4).robot == 4
    with pytest.raises(InputError, match=r"no robot 1 in this MRCLAM folder \(robots: 2, 4\)"):
        MrclamSource(folder)
    (folder / "Robot2_Measurement.dat").unlink()
    with pytest.raises(InputError, match=r"has no Robot2_Measurement\.dat"):
        MrclamSource(folder, robot=2)
    with pytest.raises(ConfigError, match="robot must be"):
        MrclamSource(folder, robot=2.0)  # type: ignore[arg-type]


# --- Victoria Park ----------------------------------------------------------------------------


def _compose(a: np.ndarray, d: list[float]) -> np.ndarray:
    c, s = math.cos(d[2]), math.sin(d[2])
    step = np.array([[c, -s, d[0]], [s, c, d[1]], [0, 0, 1.0]])
    return a @ step


def test_victoria_park_counts_and_measurements() -> None:
    path = victoria()
    rows = data_rows(path)
    n_odo = sum(f[0] == "ODOMETRY" for _, f in rows)
    lm_rows = [f for _, f in rows if f[0] == "LANDMARK"]
    with open_source(path) as src:
        assert isinstance(src, VictoriaParkSource)
        frames = list(src.frames())
        info = src.info()
    check_order(frames)
    odo, obs = split(frames)
    assert (n_odo, len(lm_rows)) == (6968, 3640)
    assert len(odo) == n_odo + 1 and sum(f.ids.size for f in obs) == len(lm_rows)
    assert {s.name: s.count for s in info.streams} == {"ODOMETRY": n_odo, "LANDMARK": len(lm_rows)}
    assert info.groundtruth == 0 and src.groundtruth() is None and src.landmark_truth() is None
    assert src.start_pose() is None
    ids = np.concatenate([f.ids for f in obs])
    x = np.array([float(f[3]) for f in lm_rows])
    y = np.array([float(f[4]) for f in lm_rows])
    assert ids.tolist() == [int(f[2]) for f in lm_rows]
    assert np.allclose(np.concatenate([f.ranges_m for f in obs]), np.hypot(x, y))
    assert np.allclose(np.concatenate([f.bearings_rad for f in obs]), np.arctan2(y, x))
    # Stamps: the k-th pose of the chain at k seconds; pose 0 first, at the origin.
    assert [f.stamp_ns for f in odo[:3]] == [0, VICTORIA_STEP_NS, 2 * VICTORIA_STEP_NS]
    assert frames[0] is odo[0] and np.array_equal(odo[0].world_from_body, np.eye(4))
    assert all(f.v is None and f.omega is None for f in odo[:10])
    # The first landmark line is seen from pose key 4, the 4th pose.
    assert obs[0].stamp_ns == 4 * VICTORIA_STEP_NS
    assert src.pose_keys[:7].tolist() == [0, 1, 2, 3, 4, 6, 7]
    assert src.odometry_covariances.shape == (n_odo, 3, 3)
    assert src.odometry_covariances[0, 0, 0] == pytest.approx(1e-4)


def test_victoria_park_dead_reckoning() -> None:
    path = victoria()
    steps = [list(map(float, f[3:6])) for _, f in data_rows(path) if f[0] == "ODOMETRY"]
    with VictoriaParkSource(path) as src:
        odo, _ = split(src.frames(("odometry",)))
    pose = np.eye(3)
    for k in range(1, 60):
        pose = _compose(pose, steps[k - 1])
        got = odo[k].world_from_body
        assert got is not None
        assert np.allclose(got[:2, :2], pose[:2, :2], atol=1e-12)
        assert np.allclose(got[:2, 3], pose[:2, 2], atol=1e-12)
    # The whole chain agrees with the step-by-step composition.
    pose = np.eye(3)
    for d in steps:
        pose = _compose(pose, d)
    last = odo[-1].world_from_body
    assert last is not None and np.allclose(last[:2, 3], pose[:2, 2], atol=1e-6)


def test_victoria_park_ignore_ids() -> None:
    with open_source(victoria(), ignore_ids=True) as src:
        _, obs = split(src.frames(("landmarks",)))
    assert len(obs) > 3000 and all(np.all(f.ids == -1) for f in obs)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (
            "ODOMETRY 0 1 1 0 0 1 0 0 1 0 1\nODOMETRY 2 3 1 0 0 1 0 0 1 0 1\n",
            r":2: expected ODOMETRY from pose 1",
        ),
        (
            "ODOMETRY 0 1 1 0 0 1 0 0 1 0 1\nODOMETRY 1 1 1 0 0 1 0 0 1 0 1\n",
            r":2: expected ODOMETRY",
        ),
        (
            "ODOMETRY 0 1 1 0 0 1 0 0 1 0 1\nLANDMARK 0 5 1 1 1 0 1\n",
            r":2: LANDMARK seen from pose 0",
        ),
        (
            "ODOMETRY 0 1 1 0 0 1 0 0 1 0 1\nLANDMARK 1 5 1 1 1 0\n",
            r":2: LANDMARK has 7 values, found 6",
        ),
        ("# c\n\nODOMETRY 0 1 1 0 0 1 0 0 1 0 x\n", r":3: column 12: value 'x'"),
        ("ODOMETRY 0 1 1 0 0 1 0 0 1 0 1\nVERTEX2 1 0 0 0\n", r":2: unknown record 'VERTEX2'"),
    ],
)
def test_victoria_park_bad_lines(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "vp.txt"
    path.write_text(text)
    with pytest.raises(FormatError, match=match):
        VictoriaParkSource(path)


def test_victoria_park_small_file(tmp_path: Path) -> None:
    path = tmp_path / "vp.txt"
    path.write_text(
        "# comment\n"
        "ODOMETRY 0 1 1.0 0.0 1.5707963267948966 1 0 0 1 0 1\n"
        "LANDMARK 1 2 3.0 4.0 0.4 0 0.4\n"
        "LANDMARK 1 5 0.0 -2.0 0.4 0 0.4\n"
        "ODOMETRY 1 3 2.0 0.0 0.0 1 0 0 1 0 1\n"
    )
    src = VictoriaParkSource(path)
    frames = list(src.frames())
    assert [type(f).__name__ for f in frames] == [
        "OdometryFrame",
        "OdometryFrame",
        "LandmarkFrame",
        "OdometryFrame",
    ]
    lm = frames[2]
    assert isinstance(lm, LandmarkFrame) and lm.stamp_ns == VICTORIA_STEP_NS
    assert lm.ids.tolist() == [2, 5]
    assert np.allclose(lm.ranges_m, [5.0, 2.0])
    assert np.allclose(lm.bearings_rad, [math.atan2(4, 3), -math.pi / 2])
    last = frames[3]
    assert isinstance(last, OdometryFrame) and last.world_from_body is not None
    assert np.allclose(last.world_from_body[:2, 3], [1.0, 2.0])  # 1 m east, then 2 m north
    assert last.stamp_ns == 2 * VICTORIA_STEP_NS


# --- synth landmarks folders ------------------------------------------------------------------


def test_sample_world_counts_and_truth() -> None:
    odo_lines = (SAMPLE / "odometry.csv").read_text().splitlines()[1:]
    meas_lines = (SAMPLE / "measurements.csv").read_text().splitlines()[1:]
    with open_source(SAMPLE) as src:
        assert isinstance(src, LandmarkWorldSource)
        frames = list(src.frames())
        truth = src.landmark_truth()
        gt = src.groundtruth()
        start = src.start_pose()
    check_order(frames)
    odo, obs = split(frames)
    assert len(odo) == len(odo_lines) == 2400
    assert sum(f.ids.size for f in obs) == len(meas_lines) == 5143
    assert len(obs) == len({line.split(",")[0] for line in meas_lines})
    first = meas_lines[0].split(",")
    assert obs[0].ids[0] == int(first[1]) and obs[0].ranges_m[0] == float(first[2])
    assert truth is not None and len(truth) == 40 and truth.cov is None
    ids = set(np.concatenate([f.ids for f in obs]).tolist())
    assert ids <= set(truth.ids.tolist())
    assert gt is not None and len(gt) == 2401
    # The first frame is at the first ground-truth stamp: the start pose is that pose.
    assert start is not None and np.allclose(start, [-6.0, -5.909859317, 0.0])
    assert odo[0].v == float(odo_lines[0].split(",")[1])


def test_world_folder_errors(tmp_path: Path) -> None:
    folder = write_world(
        tmp_path / "w",
        ["1.0,0.5,0.0", "1.1,0.5", "1.2,0.5,0.0"],
        ["1.0,0,2.0,0.1"],
    )
    with pytest.raises(FormatError, match=r"odometry.csv:3: expected 3 fields"):
        open_source(folder)
    folder = write_world(
        tmp_path / "w2", ["1.0,0.5,0.0", "1.1,0.5,0.0"], ["1.1,0,2.0,0.1", "1.0,1,2.0,0.1"]
    )
    with pytest.raises(
        FormatError, match=r"measurements.csv:3: time goes backwards from 1.1 to 1.0"
    ):
        open_source(folder)
    folder = write_world(tmp_path / "w3", ["1.0,0.5,0.0"], ["1.0,0,2.0,0.1"])
    (folder / "measurements.csv").unlink()
    with pytest.raises(UnknownFormatError):
        open_source(folder)
    with pytest.raises(InputError, match=r"has no measurements\.csv"):
        LandmarkWorldSource(folder)


def test_world_folder_ignore_ids_and_no_truth(tmp_path: Path) -> None:
    folder = write_world(
        tmp_path / "w", ["1.0,0.5,0.0", "1.1,0.5,0.1"], ["1.1,3,2.0,0.1", "1.1,4,1.0,-0.1"]
    )
    src = LandmarkWorldSource(folder, ignore_ids=True)
    frames = list(src.frames())
    assert [type(f).__name__ for f in frames] == ["OdometryFrame", "OdometryFrame", "LandmarkFrame"]
    lm = frames[2]
    assert isinstance(lm, LandmarkFrame) and lm.ids.tolist() == [-1, -1]
    assert src.groundtruth() is None and src.landmark_truth() is None and src.start_pose() is None


# --- text tables ------------------------------------------------------------------------------


def test_read_table_slow_path_agrees(tmp_path: Path) -> None:
    """Stamps the bulk parser does not take (exponents, signs) go through the exact parser."""
    path = tmp_path / "t.dat"
    path.write_text("# c\r\n1.5e0 1 2\r\n\r\n-0.25 3 4\r\n1248444187.123456789 5 6\r\n")
    t = read_table(path, ("t", "a", "b"))
    assert t.stamps_ns.tolist() == [1_500_000_000, -250_000_000, 1248444187_123456789]
    assert t.lines.tolist() == [2, 4, 5]
    assert t.values.tolist() == [[1, 2], [3, 4], [5, 6]]
    path.write_text("1248444187.156 1 2\n1248444187.1 1 2\n7 1 2\n")
    fast = read_table(path, ("t", "a", "b"))
    assert fast.stamps_ns.tolist() == [1248444187_156000000, 1248444187_100000000, 7_000_000_000]


# --- registry, sniffing and the CLI -----------------------------------------------------------


def test_sniffing_picks_the_right_class(tmp_path: Path) -> None:
    mini = write_mrclam(tmp_path / "m")
    vp = tmp_path / "vp.txt"
    vp.write_text("# a comment\n\nLANDMARK 0 5 1 1 1 0 1\n")
    other = tmp_path / "other.txt"
    other.write_text("EDGE2 0 1 1 0 0\n")
    assert {"mrclam", "victoria", "landmarks"} <= set(SOURCES)
    for name in SOURCES:
        cls = source_class(name)
        assert cls.sniff(mini) == (name == "mrclam"), name
        assert cls.sniff(vp) == (name == "victoria"), name
        assert cls.sniff(SAMPLE) == (name == "landmarks"), name
        assert not cls.sniff(other), name
    assert isinstance(open_source(vp), VictoriaParkSource)
    assert issubclass(MrclamSource, LandmarkSource)
    with pytest.raises(UnknownFormatError, match=r"MRCLAM folder Barcodes\.dat"):
        open_source(other)


def test_landmark_options_are_rejected_by_tum_folders() -> None:
    tum = SAMPLE.parent / "rgbd_room"
    assert TumRgbdSource.sniff(tum)
    with pytest.raises(ConfigError, match="--robot does not apply to tum inputs"):
        open_source(tum, robot=2)
    with pytest.raises(ConfigError, match="--ignore-ids does not apply"):
        open_source(tum, ignore_ids=True)
    with pytest.raises(ConfigError, match="--robot does not apply to landmarks inputs"):
        open_source(SAMPLE, robot=2)


def test_cli_info_mrclam() -> None:
    folder = mrclam()
    n_odo = len(data_rows(folder / "Robot2_Odometry.dat"))
    res = invoke(folder, "--robot", "2")
    assert res.exit_code == 0, res.output
    for text in ("mrclam", "Robot2_Odometry.dat", str(n_odo), "robot sightings", "15 surveyed"):
        assert text in res.stdout, text
    res = invoke(folder, "--robot", "2", "--json", "--ignore-ids")
    data = json.loads(res.stdout)
    assert data["format"] == "mrclam" and data["details"]["robot"] == 2
    assert data["details"]["odometry"] == n_odo and data["details"]["ignore_ids"] is True
    res = invoke(folder, "--robot", "9")
    assert res.exit_code == 1 and "robots: 1, 2, 3, 4, 5" in res.stderr


def test_cli_info_victoria_and_world() -> None:
    res = invoke(victoria())
    assert res.exit_code == 0, res.output
    assert "victoria" in res.stdout and "6968" in res.stdout and "3640" in res.stdout
    res = invoke(SAMPLE)
    assert res.exit_code == 0, res.output
    for text in ("odometry.csv", "2400", "5143", "40 surveyed", "start pose", "no problems found"):
        assert text in res.stdout, text
    res = invoke(SAMPLE, "--robot", "1")
    assert res.exit_code == 1 and "--robot does not apply" in res.stderr


def test_mrclam_real_subjects_are_five_robots_and_fifteen_landmarks() -> None:
    with MrclamSource(mrclam(), robot=3) as src:
        assert src.robots == [1, 2, 3, 4, 5]
        assert src.robot_subjects == frozenset(range(1, 6))
        assert src.landmark_subjects == frozenset(range(6, 21))


def test_mrclam_robots_beyond_five_come_from_the_robot_files(tmp_path: Path) -> None:
    # With Landmark_Groundtruth.dat a surveyed subject stays a landmark, robot files or not.
    surveyed = write_mrclam(tmp_path / "a", robots=(1, 8))
    with MrclamSource(surveyed, robot=8) as src:
        assert src.robots == [1, 8]
        assert src.robot_subjects == frozenset(range(1, 6))
        assert src.observations.ids.tolist() == [6, 7, 8]
    # Without it, a subject with a RobotK file is a robot: its barcode (81) is a sighting.
    folder = write_mrclam(tmp_path / "b", robots=(1, 7))
    (folder / "Landmark_Groundtruth.dat").unlink()
    with MrclamSource(folder, robot="1,7") as src:
        assert src.robot_subjects == frozenset({1, 2, 3, 4, 5, 7})
        assert src.landmark_subjects == frozenset({6, 8})
        assert src.observations.ids.tolist() == [6, 8]
        assert src.sightings.ids.tolist() == [2, 7]
        assert src.robot_sightings == 2
