"""Kalibr calibration files (``--calib``): reading the camera chain and the IMU file, and what
they replace in a EuRoC folder; the log runs with them are in ``test_visual_stereo.py``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import shared_path
from kalibr_files import write_kalibr

from slamcli.errors import ConfigError, FormatError, InputError
from slamcli.formats import open_source
from slamcli.formats.euroc.kalibr import read_kalibr
from slamcli.source_options import SourceOptions

EUROC = ("stereo", "euroc_V1_01_micro")


@pytest.fixture(scope="module")
def kalibr(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    return write_kalibr(shared_path(*EUROC), tmp_path_factory.mktemp("kalibr"))


def _edit(src: Path, dest: Path, edit) -> Path:
    data = yaml.safe_load(src.read_text())
    edit(data)
    dest.write_text(yaml.safe_dump(data, default_flow_style=None))
    return dest


def test_the_chain_and_imu_file_are_read_on_the_imu(kalibr: tuple[Path, Path]) -> None:
    camchain, imu = kalibr
    calib = read_kalibr([camchain, imu])
    assert calib.imu_placed
    assert len(calib.cameras) == 2
    assert calib.camera_topics == ("/cam0/image_raw", "/cam1/image_raw")
    assert calib.imu is not None and calib.imu_topic == "/imu0"
    assert calib.imu.rate_hz == 200.0
    assert calib.imu.gyroscope_noise_density == pytest.approx(1.6968e-4)
    assert np.array_equal(calib.imu.body_from_sensor, np.eye(4))
    # cam1 sits 0.11 m to the right of cam0 (x of cam0's frame).
    cam0, cam1 = (c.body_from_sensor for c in calib.cameras)
    offset = np.linalg.inv(cam0) @ cam1
    assert offset[0, 3] == pytest.approx(0.110, abs=0.001)


def test_a_folder_with_its_own_calibration_as_kalibr_files_gives_the_same_rig(
    kalibr: tuple[Path, Path], tmp_path: Path
) -> None:
    folder = shared_path(*EUROC)
    own = open_source(folder)
    with_calib = open_source(folder, calib=[str(p) for p in kalibr])
    assert np.allclose(own.rig.body_from_left, with_calib.rig.body_from_left, atol=1e-9)
    assert own.rig.baseline_m == pytest.approx(with_calib.rig.baseline_m, abs=1e-9)
    assert own.rig.camera.fx == pytest.approx(with_calib.rig.camera.fx, abs=1e-6)
    info = with_calib.info()
    assert "--calib" in info.camera_source
    assert info.details["calib"]["body"] == "imu"
    assert info.details["imu"]["body_from_imu"] == np.eye(4).tolist()
    # A chain from a camera-only calibration (T_cn_cnm1, no T_cam_imu) keeps the folder's
    # mounting of cam0: the same rig again.
    chain, _ = write_kalibr(folder, tmp_path, imu_placed=False)
    camera_only = open_source(folder, calib=[str(chain)])
    assert np.allclose(own.rig.body_from_left, camera_only.rig.body_from_left, atol=1e-9)


def test_the_time_shift_puts_the_images_on_the_imus_clock(
    kalibr: tuple[Path, Path], tmp_path: Path
) -> None:
    camchain, imu = kalibr

    def shift(data: dict) -> None:
        data["cam0"]["timeshift_cam_imu"] = 0.002

    shifted = _edit(camchain, tmp_path / "camchain-imucam.yaml", shift)
    folder = shared_path(*EUROC)
    own = open_source(folder)
    moved = open_source(folder, calib=[str(shifted), str(imu)])
    assert np.array_equal(moved.pair_stamps_ns - own.pair_stamps_ns, np.full(len(own), 2_000_000))


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d["cam0"].__setitem__("camera_model", "omni"), "expected 'pinhole'"),
        (lambda d: d["cam0"].__setitem__("distortion_model", "fov"), "radtan, equidistant"),
        (lambda d: d["cam0"].pop("intrinsics"), "missing key 'intrinsics'"),
        (lambda d: d["cam0"].__setitem__("intrinsics", [1, 2, 3]), "cam0.intrinsics"),
        (
            lambda d: d["cam0"]["T_cam_imu"][0].__setitem__(0, 2.0),
            "cam0.T_cam_imu': not a rigid transform",
        ),
        (lambda d: d["cam1"]["T_cam_imu"].pop(), "cam1.T_cam_imu: expected four rows"),
        (lambda d: d["cam0"].__setitem__("timeshift_cam_imu", 40.0), "timeshift_cam_imu"),
    ],
)
def test_a_bad_chain_is_refused_naming_file_and_key(
    kalibr: tuple[Path, Path],
    tmp_path: Path,
    edit,
    message: str,
) -> None:
    bad = _edit(kalibr[0], tmp_path / "camchain.yaml", edit)
    with pytest.raises(FormatError) as err:
        read_kalibr([bad])
    assert str(bad) in str(err.value)
    assert message in str(err.value)


def test_files_of_neither_kind_or_twice_one_kind_are_refused(
    kalibr: tuple[Path, Path], tmp_path: Path
) -> None:
    imu = kalibr[1]
    other = tmp_path / "target.yaml"
    other.write_text("target_type: aprilgrid\ntagCols: 6\n")
    with pytest.raises(FormatError, match="neither a Kalibr camera chain"):
        read_kalibr([other])
    with pytest.raises(InputError, match="two IMU files"):
        read_kalibr([imu, imu])
    with pytest.raises(InputError, match="no such file"):
        read_kalibr([tmp_path / "missing.yaml"])
    no_rate = _edit(imu, tmp_path / "imu.yaml", lambda d: d.pop("update_rate"))
    with pytest.raises(FormatError, match="missing key 'update_rate'"):
        read_kalibr([no_rate])
    # Kalibr's results nest the IMU under imu0.
    nested = tmp_path / "imu-results.yaml"
    nested.write_text(yaml.safe_dump({"imu0": yaml.safe_load(imu.read_text())}))
    assert read_kalibr([nested]).imu is not None


def test_an_imu_file_alone_needs_something_to_place_the_imu(
    kalibr: tuple[Path, Path],
) -> None:
    calib = read_kalibr([kalibr[1]])
    with pytest.raises(InputError, match="nothing places it"):
        calib.imu_on_body(None)
    placed = calib.imu_on_body(np.eye(4))
    assert placed is not None


def test_calib_is_a_source_option_of_the_inputs_it_fits(kalibr: tuple[Path, Path]) -> None:
    options = SourceOptions.from_mapping({"calib": str(kalibr[1])})
    assert options.calib == (str(kalibr[1]),)
    assert SourceOptions.from_mapping({"calib": [str(p) for p in kalibr]}).calib == tuple(
        str(p) for p in kalibr
    )
    with pytest.raises(ConfigError, match="--calib does not apply to tum"):
        open_source(shared_path("tum", "rgbd_dataset_freiburg1_rpy_excerpt"), calib=["x.yaml"])
