"""Bad IMU data in a visual-inertial run, on copies of the MH_05 excerpt: units and clocks that
would give a wrong map refuse the run (exit 1) naming the stream and what to do; gaps,
repeated stamps and saturated samples let it finish on what is left, as lost data (exit 3,
listed in run.json); a camera-IMU transform that is missing or not a rotation is refused."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path
from typer.testing import CliRunner

from slamcli.cli.app import app

runner = CliRunner()
IMU_CSV = Path("mav0", "imu0", "data.csv")
CAM_YAML = Path("mav0", "cam0", "sensor.yaml")


def _copy(tmp_path: Path) -> Path:
    """A copy of MH_05 whose IMU and sensor files may be edited (the images linked)."""
    src = shared_path("vi", "euroc_MH05_a")
    dest = tmp_path / "mh05"
    shutil.copytree(src, dest, ignore=shutil.ignore_patterns("*.png"))
    for png in (src / "mav0" / "cam0" / "data").iterdir():
        (dest / "mav0" / "cam0" / "data" / png.name).symlink_to(png)
    return dest


def _imu(folder: Path) -> tuple[list[str], np.ndarray]:
    lines = (folder / IMU_CSV).read_text().splitlines()
    header = [line for line in lines if line.startswith("#")]
    rows = np.array([[float(x) for x in line.split(",")] for line in lines if line[:1].isdigit()])
    return header, rows


def _write_imu(folder: Path, header: list[str], rows: np.ndarray) -> None:
    body = [",".join([str(int(r[0])), *(f"{v:.12g}" for v in r[1:])]) for r in rows]
    (folder / IMU_CSV).write_text("\n".join([*header, *body]) + "\n")


def _run(folder: Path, tmp_path: Path) -> object:
    return runner.invoke(app, ["run", "visual", str(folder), "--out", str(tmp_path / "run")])


def _record(tmp_path: Path) -> dict:
    return json.loads((tmp_path / "run" / "run.json").read_text())


def test_gyro_in_degrees_per_second_is_refused(tmp_path: Path) -> None:
    folder = _copy(tmp_path)
    header, rows = _imu(folder)
    rows[:, 1:4] = np.degrees(rows[:, 1:4])
    _write_imu(folder, header, rows)
    res = _run(folder, tmp_path)
    assert res.exit_code == 1, res.output
    assert "deg/s" in res.output and "imu=false" in res.output
    assert not (tmp_path / "run").exists()


def test_imu_clock_off_the_camera_is_refused(tmp_path: Path) -> None:
    """The IMU's stamps 5 s late: no image has IMU samples around it."""
    folder = _copy(tmp_path)
    header, rows = _imu(folder)
    rows[:, 0] += 5e9
    _write_imu(folder, header, rows)
    res = _run(folder, tmp_path)
    assert res.exit_code == 1, res.output
    assert "clock" in res.output and "imu0/data.csv" in res.output


def test_lost_imu_data_finishes_with_exit_3(tmp_path: Path) -> None:
    """Repeated stamps, a gap and a clipped gyroscope in one log: the run uses what is left,
    names each loss, and exits 3."""
    folder = _copy(tmp_path)
    header, rows = _imu(folder)
    quarter, middle = len(rows) // 4, len(rows) // 2
    top = np.percentile(rows[:, 1], 95)
    rows[:, 1] = np.minimum(rows[:, 1], top)  # the gyroscope's x clipped at its range
    rows = np.concatenate(
        [
            rows[:quarter],
            rows[quarter - 10 : quarter],  # ten samples written twice
            rows[quarter:middle],
            rows[middle + 30 :],  # 0.15 s without samples
        ]
    )
    _write_imu(folder, header, rows)
    res = _run(folder, tmp_path)
    assert res.exit_code == 3, res.output
    assert "the input is damaged" in res.output
    lost = _record(tmp_path)["data_loss"]
    for word in ("repeat", "gap", "extreme"):
        assert any(word in line for line in lost), (word, lost)
    # The run itself went through, metric.
    assert _record(tmp_path)["metrics"]["inertial"]["initialised"]


def test_imu_clock_a_frame_and_a_half_off_is_found_from_the_motion(tmp_path: Path) -> None:
    """The IMU's stamps 75 ms late (a frame and a half at 20 Hz): every image still has IMU
    samples around it, so the stamps cannot show it; the map's turns against the gyroscope's
    do, and the refusal says by how much and what to give."""
    folder = _copy(tmp_path)
    header, rows = _imu(folder)
    rows[:, 0] += 75e6
    _write_imu(folder, header, rows)
    res = _run(folder, tmp_path)
    inertial = _record(tmp_path)["metrics"]["inertial"]
    assert not inertial["initialised"]
    assert 0.06 <= inertial["clock_offset"]["shift_s"] <= 0.09, inertial
    assert "timeshift_cam_imu" in inertial["last_refusal"] and "late" in inertial["last_refusal"]
    assert "timeshift_cam_imu" in res.output  # the doubt, on the terminal too


@pytest.mark.parametrize("damage", ["missing", "not a rotation"])
def test_bad_camera_imu_transform_is_refused(tmp_path: Path, damage: str) -> None:
    folder = _copy(tmp_path)
    text = (folder / CAM_YAML).read_text()
    if damage == "missing":
        start = text.index("T_BS:")
        end = text.index("]", start) + 1
        text = text[:start] + text[end:]
    else:
        # The rotation's first entry doubled: no longer a rotation.
        head, _, tail = text.partition("data: [")
        first, _, rest = tail.partition(",")
        text = head + "data: [" + repr(2.0 * float(first)) + "," + rest
    (folder / CAM_YAML).write_text(text)
    res = _run(folder, tmp_path)
    assert res.exit_code == 1, res.output
    assert "T_BS" in res.output and "sensor.yaml" in res.output
