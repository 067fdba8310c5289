"""CARMEN laser logs: the shared Radish logs, beam angles, broken stamps, damage, options,
the writer's round trips and sniffing."""

from __future__ import annotations

import gzip
import logging
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path

from slamcli.errors import ConfigError, FormatError, InputError
from slamcli.formats import open_source
from slamcli.formats.base import Frame, Source
from slamcli.formats.carmen import DEFAULT_MAX_RANGE_M, CarmenSource, write_carmen
from slamcli.geometry import se3_to_planar
from slamcli.types import OdometryFrame, ScanFrame

LOGGER = "slamcli.formats.carmen"
FLASER_RANGE_MAX = float(np.nextafter(np.float32(DEFAULT_MAX_RANGE_M), np.float32(0)))


def _write(path: Path, lines: list[str]) -> Path:
    path.write_text("# message formats defined: PARAM ODOM FLASER\n" + "\n".join(lines) + "\n")
    return path


def _flaser(
    t: float | str,
    ranges: list[float] | int = 180,
    robot: tuple[float, float, float] = (1.0, 2.0, 0.5),
    laser: tuple[float, float, float] | None = None,
    keyword: str = "FLASER",
) -> str:
    r = [1.0 + 0.01 * i for i in range(ranges)] if isinstance(ranges, int) else ranges
    pose = " ".join(map(str, (laser or robot) + robot))
    return f"{keyword} {len(r)} {' '.join(map(str, r))} {pose} {t} host {t}"


def _odom(t: float | str, x: float = 0.0) -> str:
    return f"ODOM {x} 0 0 0 0 0 {t} host {t}"


def _frames(src: Source) -> tuple[list[ScanFrame], list[OdometryFrame], list[Frame]]:
    frames = list(src.frames())
    scans = [f for f in frames if isinstance(f, ScanFrame)]
    odometry = [f for f in frames if isinstance(f, OdometryFrame)]
    return scans, odometry, frames


def _strictly_increasing(frames: list[ScanFrame] | list[OdometryFrame]) -> bool:
    stamps = np.array([f.stamp_ns for f in frames], dtype=np.int64)
    return bool(np.all(np.diff(stamps) > 0))


# -- the shared Radish logs -------------------------------------------------------------------

# Scan-pose path lengths measured on these files: intel 499.5 m, aces 323.2 m, csail 379.6 m.
# The bands (about +-5 %) fail if scans are lost or the laser/robot pose columns are mixed up;
# the mean speeds over the logged scan times (intel 0.19 m/s, aces 0.25 m/s) must be those of
# an indoor Pioneer-class robot, 0.1 to 0.5 m/s (the CSAIL log's clock is unusable, see below).
SHARED = [
    ("intel", 910, 180, (475.0, 525.0), True),
    ("aces", 440, 180, (307.0, 340.0), True),
    ("csail", 406, 361, (360.0, 400.0), False),
]


@pytest.mark.parametrize(("name", "count", "beams", "length", "clock"), SHARED)
def test_shared_logs(
    name: str, count: int, beams: int, length: tuple[float, float], clock: bool
) -> None:
    path = shared_path("lidar", "carmen", f"{name}-corrected.log.gz")
    src = open_source(path, groundtruth="log")
    assert isinstance(src, CarmenSource)
    scans, odometry, frames = _frames(src)
    assert len(scans) == count
    assert {len(s.ranges_m) for s in scans} == {beams}
    assert _strictly_increasing(scans) and _strictly_increasing(odometry)
    stamps = np.array([f.stamp_ns for f in frames])
    assert np.all(np.diff(stamps) >= 0)  # file order is time order
    # One pose per scan: each scan comes right after an odometry frame at its stamp.
    for k, frame in enumerate(frames):
        if isinstance(frame, ScanFrame):
            before = frames[k - 1]
            assert isinstance(before, OdometryFrame) and before.stamp_ns == frame.stamp_ns
    gt = src.groundtruth()
    assert gt is not None and len(gt) == count
    assert np.array_equal(gt.stamps_ns, [s.stamp_ns for s in scans])
    travelled = float(np.linalg.norm(np.diff(gt.positions[:, :2], axis=0), axis=1).sum())
    assert length[0] < travelled < length[1]
    if clock:
        duration_s = (scans[-1].stamp_ns - scans[0].stamp_ns) * 1e-9
        assert 0.1 < travelled / duration_s < 0.5
    # The SICK no-return codes (81.83 / 81.91 m) and the ACES 50 m clip are no returns.
    readings = np.concatenate([s.ranges_m[s.readings()] for s in scans])
    assert readings.max() < 50.0 and readings.min() >= 0.01
    assert sum(int(s.no_returns().sum()) for s in scans) > 100
    info = src.info()
    assert info.details["beams_per_scan"] == [beams]
    assert info.details["messages"]["FLASER"] == count
    assert info.details["skipped_messages"]["NEFF"] == count
    # Every one of these logs has broken times (zeros after each scan, %g printing).
    assert info.details["stamps_replaced"] > 0
    assert info.details["clock"] == ("repaired" if clock else "ignored (fixed step)")


def test_shared_log_scan_times_are_kept() -> None:
    """The ACES scans' own times are all usable: none is replaced, whatever the ODOM lines."""
    src = CarmenSource(shared_path("lidar", "carmen", "aces-corrected.log.gz"))
    scans, _, _ = _frames(src)
    assert scans[0].stamp_ns == 21_019_900_000  # "FLASER ... 21.0199 pippo 21.0199"
    assert src.info().details["stamps_replaced"] == 440  # the "ODOM ... 0 pippo 0" lines


# -- beam angles and mounting -----------------------------------------------------------------


def test_flaser_angles_follow_carmen(tmp_path: Path) -> None:
    path = _write(
        tmp_path / "angles.log",
        [_flaser(1.0 + k, n) for k, n in enumerate((180, 181, 360, 361, 90))],
    )
    scans, _, _ = _frames(CarmenSource(path))
    first = [s.angles()[0] for s in scans]
    last = [s.angles()[-1] for s in scans]
    assert np.allclose(first, -math.pi / 2)
    # 180 and 360 beams: a 181/361-beam sweep without its last beam (pi/n apart).
    assert np.allclose(last, np.radians([89.0, 90.0, 89.5, 90.0, 90.0]))
    assert scans[0].angle_increment_rad == pytest.approx(math.pi / 180)
    assert scans[2].angle_increment_rad == pytest.approx(math.pi / 360)
    assert scans[4].angle_increment_rad == pytest.approx(math.pi / 89)


def test_rear_laser_faces_backwards(tmp_path: Path) -> None:
    robot = (3.0, 1.0, 0.3)
    behind = (3.0 - 0.2 * math.cos(0.3), 1.0 - 0.2 * math.sin(0.3))
    path = _write(
        tmp_path / "rear.log",
        [
            _flaser(1.0, 180, robot, (*behind, 0.3), "RLASER"),
            _flaser(2.0, 180, robot, (*behind, 0.3 + math.pi), "RLASER"),
            _flaser(3.0, 180, robot, (3.1, 1.0, 0.3)),
        ],
    )
    scans, _, _ = _frames(CarmenSource(path))
    for scan in scans[:2]:
        x, y, yaw = scan.body_from_sensor
        assert (x, y) == pytest.approx((-0.2, 0.0), abs=1e-9)
        assert abs(yaw) == pytest.approx(math.pi)
    assert scans[2].body_from_sensor[2] == pytest.approx(0.0, abs=1e-12)
    assert scans[2].body_from_sensor[0] == pytest.approx(0.1 * math.cos(0.3), abs=1e-9)


def test_robotlaser_carries_its_setup(tmp_path: Path) -> None:
    ranges = "1.5 20 0.005 3.25 7"
    laser = f"{1.0 + 0.25 * math.cos(0.1)!r} {2.0 + 0.25 * math.sin(0.1)!r} 0.1"
    line = (
        f"ROBOTLASER1 0 -2.0 0.04 0.01 20 0.01 0 5 {ranges} 2 9 9 "
        f"{laser} 1.0 2.0 0.1 0.3 0.0 0.5 0.2 1000000 5.5 host 5.5"
    )
    raw = "RAWLASER1 0 -1.0 0.02 0.005 8 0.01 0 5 1 2 3 4 8.5 0 6.5 host 6.5"
    path = _write(tmp_path / "robot.clf", [line, raw])
    scans, odometry, _ = _frames(CarmenSource(path))
    scan, rawscan = scans
    assert scan.angle_min_rad == -2.0 and scan.angle_increment_rad == 0.01
    # 20 m is the maximum range: no return; 0.005 m is below the minimum: not a reading.
    assert scan.readings().tolist() == [True, False, False, True, True]
    assert scan.no_returns().tolist() == [False, True, False, False, False]
    assert scan.body_from_sensor == pytest.approx([0.25, 0.0, 0.0], abs=1e-12)
    assert len(odometry) == 1 and odometry[0].stamp_ns == scan.stamp_ns == 5_500_000_000
    assert rawscan.no_returns().tolist() == [False] * 4 + [True]  # 8.5 >= its maximum of 8
    assert np.array_equal(rawscan.body_from_sensor, np.zeros(3))


# -- broken stamps ----------------------------------------------------------------------------


def _warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [
        r.getMessage()
        for r in caplog.records
        if r.levelno == logging.WARNING and r.name.startswith(LOGGER)
    ]


@pytest.mark.parametrize(
    ("case", "times", "first_bad"),
    [
        ("zero", ["0"] * 8, 0),
        ("wrap", [f"{4294967294 + 0.2 * k:.1f}" for k in range(6)] + ["0.1", "0.3"], 6),
        ("negative", ["1.0", "1.2", "-3.0", "1.6", "1.8", "2.0", "2.2", "2.4"], 2),
    ],
)
def test_broken_stamps_are_replaced_with_one_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, case: str, times: list[str], first_bad: int
) -> None:
    # Alternate ODOM and FLASER lines; line 1 is the header comment.
    lines = [_odom(t, k) if k % 2 == 0 else _flaser(t) for k, t in enumerate(times)]
    path = _write(tmp_path / f"{case}.log", lines)
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        src = CarmenSource(path)
        scans, odometry, frames = _frames(src)
    assert len(scans) == 4 and len(odometry) == 8  # 4 ODOM lines and 4 scans' poses
    assert _strictly_increasing(scans) and _strictly_increasing(odometry)
    assert np.all(np.diff([f.stamp_ns for f in frames]) >= 0)
    warnings = _warnings(caplog)
    assert len(warnings) == 1
    assert warnings[0].startswith(f"{path}:{first_bad + 2}: ")
    assert src.info().details["first_replaced_stamp"] == f"{path.name}:{first_bad + 2}"
    if case == "negative":
        # Between its neighbours' 1.2 s and 1.6 s; the others keep their own times.
        assert odometry[2].stamp_ns == 1_400_000_000 and scans[0].stamp_ns == 1_200_000_000
    if case == "wrap":
        assert scans[-1].stamp_ns > 4_294_967_295 * 10**9


# -- damage -----------------------------------------------------------------------------------


def test_truncated_line(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    cut = _flaser(2.0)[:300]
    path = _write(tmp_path / "cut.log", [_flaser(1.0), _odom(1.5), cut, _flaser(3.0)])
    with pytest.raises(FormatError, match=r"cut\.log:4: FLASER with 180 beams has 191 fields"):
        CarmenSource(path, strict=True)
    with caplog.at_level(logging.WARNING, logger=LOGGER):
        src = CarmenSource(path)
    assert any("cut.log:4" in w for w in _warnings(caplog))
    scans, _, _ = _frames(src)
    assert len(scans) == 2
    assert src.info().details["damaged_lines"] == 1
    assert src.stats.skipped == 1 and len(src.stats.data_loss) == 1


@pytest.mark.parametrize(
    ("line", "message"),
    [
        (_flaser(1.0).replace(" 1.05 ", " x ", 1), r"column 8: range 'x' is not a number"),
        ("ODOM 0.0 0 nan 0 0 0 1.0 host 1.0", "column 4: pose value 'nan' is not finite"),
        ("FLASER 3 1 2 0 0 0 0 0 0 1.0 host 1.0", r"FLASER with 3 beams has 14 fields, found 13"),
        ("FLASER 0 0 0 0 0 0 0 1.0 host 1.0", "FLASER beam count is 0"),
        (_odom("soon"), "column 8: time 'soon' is not a number"),
    ],
)
def test_malformed_lines_name_file_and_line(tmp_path: Path, line: str, message: str) -> None:
    path = _write(tmp_path / "bad.log", [_odom(0.5), line])
    with pytest.raises(FormatError, match=r"bad\.log:3: " + message):
        CarmenSource(path, strict=True)


def test_cut_gzip_stream(tmp_path: Path) -> None:
    whole = write_carmen(tmp_path / "whole.log.gz", _scans(40, pose=True))
    cut = tmp_path / "cut.log.gz"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    with pytest.raises(FormatError, match="compressed data is damaged or cut short"):
        CarmenSource(cut, strict=True)
    src = CarmenSource(cut)
    scans, _, _ = _frames(src)
    assert 0 < len(scans) < 40
    assert any("cut short" in p for p in src.info().problems)


# -- options ----------------------------------------------------------------------------------


def test_odometry_none_and_groundtruth_log(tmp_path: Path) -> None:
    poses = [(0.0, 0.0, 0.0), (1.0, 0.5, 0.2), (2.0, 1.5, 0.4)]
    lines = [_odom(0.5)] + [_flaser(1.0 + k, 180, p) for k, p in enumerate(poses)]
    path = _write(tmp_path / "poses.log", lines)
    scans, odometry, _ = _frames(CarmenSource(path, odometry="none", groundtruth="log"))
    assert len(scans) == 3 and odometry == []
    src = CarmenSource(path, groundtruth="log")
    gt = src.groundtruth()
    assert gt is not None
    assert np.allclose(se3_to_planar(gt.world_from_body), poses)
    assert gt.stamps_ns.tolist() == [1_000_000_000, 2_000_000_000, 3_000_000_000]
    assert src.start_pose() == pytest.approx(poses[0])
    assert CarmenSource(path).groundtruth() is None
    assert len(list(src.frames(["odometry"]))) == 4


def test_max_range_option(tmp_path: Path) -> None:
    path = _write(tmp_path / "far.log", [_flaser(1.0, [5.0, 12.0, 30.0, 49.9, 50.0, 81.91])])
    (scan,), _, _ = _frames(CarmenSource(path))
    assert scan.readings().tolist() == [True] * 4 + [False, False]
    (scan,), _, _ = _frames(CarmenSource(path, max_range=12.0))
    assert scan.readings().tolist() == [True] + [False] * 5


@pytest.mark.parametrize(
    "options",
    [{"odometry": "wheel"}, {"groundtruth": "vicon"}, {"max_range": -1.0}, {"strict": "yes"}],
)
def test_bad_options(tmp_path: Path, options: dict[str, object]) -> None:
    path = _write(tmp_path / "a.log", [_flaser(1.0)])
    with pytest.raises(ConfigError, match=next(iter(options))):
        CarmenSource(path, **options)  # type: ignore[arg-type]


def test_unknown_frame_kind(tmp_path: Path) -> None:
    src = CarmenSource(_write(tmp_path / "a.log", [_flaser(1.0)]))
    with pytest.raises(ConfigError, match="no rgbd frames"):
        list(src.frames(["rgbd"]))


# -- writing ----------------------------------------------------------------------------------


def _scans(
    n_scans: int,
    beams: int = 180,
    angle_min: float = -math.pi / 2,
    increment: float = math.pi / 180,
    range_max: float = FLASER_RANGE_MAX,
    pose: bool = True,
) -> list[tuple[ScanFrame, np.ndarray | None]]:
    rng = np.random.default_rng(7)
    out: list[tuple[ScanFrame, np.ndarray | None]] = []
    for k in range(n_scans):
        ranges = rng.uniform(0.3, min(range_max, 40.0), beams).astype(np.float32)
        ranges[3] = np.inf  # no return
        ranges[4] = 0.0  # too close
        scan = ScanFrame(
            1_700_000_000_123_456_789 + k * 100_000_000,
            ranges,
            angle_min,
            increment,
            0.01,
            range_max,
            np.array([0.12, -0.03, 0.01 * k]),
        )
        robot = np.array([0.5 * k, -0.25 * k, 0.1 * k - 0.3]) if pose else None
        out.append((scan, robot))
    return out


@pytest.mark.parametrize("suffix", [".log", ".log.gz"])
@pytest.mark.parametrize(
    ("kind", "setup"),
    [
        ("FLASER", {}),
        (
            "ROBOTLASER1",
            {
                "beams": 541,
                "angle_min": -2.356194490192345,
                "increment": 0.004363323129985824,
                "range_max": 30.0,
            },
        ),
        ("RAWLASER1", {"pose": False}),
    ],
)
def test_write_round_trip(tmp_path: Path, suffix: str, kind: str, setup: dict[str, object]) -> None:
    written = _scans(5, **setup)  # type: ignore[arg-type]
    path = write_carmen(tmp_path / f"out{suffix}", written)
    with gzip.open(path, "rt") if suffix.endswith(".gz") else path.open() as fh:
        keywords = {line.split()[0] for line in fh if not line.startswith("#")}
    assert keywords == {kind}
    src = open_source(path, groundtruth="log")
    scans, odometry, _ = _frames(src)
    assert len(scans) == 5 and src.info().details["stamps_replaced"] == 0
    for (orig, robot), back in zip(written, scans, strict=True):
        assert abs(back.stamp_ns - orig.stamp_ns) <= 500  # to the microsecond
        assert np.array_equal(back.readings(), orig.readings())
        assert np.array_equal(back.no_returns(), orig.no_returns())
        assert np.array_equal(back.ranges_m[back.readings()], orig.ranges_m[orig.readings()])
        assert back.angle_min_rad == pytest.approx(orig.angle_min_rad, abs=1e-15)
        assert back.angle_increment_rad == pytest.approx(orig.angle_increment_rad, rel=1e-15)
        assert back.range_max_m == pytest.approx(orig.range_max_m, rel=1e-7)
        if robot is not None:
            assert back.body_from_sensor == pytest.approx(orig.body_from_sensor, abs=1e-12)
    if kind == "RAWLASER1":
        assert odometry == [] and src.groundtruth() is None
        return
    gt = src.groundtruth()
    assert gt is not None
    robots = np.array([r for _, r in written if r is not None])
    assert np.allclose(se3_to_planar(gt.world_from_body), robots, atol=1e-12)
    assert [o.stamp_ns for o in odometry] == [s.stamp_ns for s in scans]


def test_write_is_deterministic_gzip(tmp_path: Path) -> None:
    a = write_carmen(tmp_path / "a.log.gz", _scans(3))
    b = write_carmen(tmp_path / "b.log.gz", _scans(3))
    assert a.read_bytes()[:2] == b"\x1f\x8b" and a.read_bytes() == b.read_bytes()


def test_write_refuses_unordered_stamps(tmp_path: Path) -> None:
    scans = _scans(3)
    with pytest.raises(InputError, match=r"scan 2 .* not after the previous"):
        write_carmen(tmp_path / "x.log", [scans[0], scans[1], scans[1]])
    assert not (tmp_path / "x.log").exists()


# -- sniffing ---------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["intel", "aces", "csail"])
def test_open_source_picks_carmen_for_the_shared_logs(name: str) -> None:
    src = open_source(shared_path("lidar", "carmen", f"{name}-corrected.log.gz"))
    assert src.format_name == "carmen"


def test_open_source_picks_carmen_by_suffix_and_content(tmp_path: Path) -> None:
    clf = write_carmen(tmp_path / "run.clf", _scans(2))
    assert open_source(clf).format_name == "carmen"
    packed = tmp_path / "packed.log"  # gzip without the .gz suffix
    packed.write_bytes(gzip.compress(clf.read_bytes()))
    src = open_source(packed)
    assert src.format_name == "carmen" and len(_frames(src)[0]) == 2
    other = tmp_path / "notes.log"
    other.write_text("# a log of something else\nstarted 12:00\n")
    assert not CarmenSource.sniff(other)
    text = tmp_path / "run.txt"
    text.write_bytes(clf.read_bytes())
    assert not CarmenSource.sniff(text)
