"""Kalibr calibration files written from an ASL folder's ``sensor.yaml`` files, as a
camera-IMU calibration of the same rig would give them (``camchain-imucam.yaml`` and
``imu.yaml``), for the ``--calib`` tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from slamcli.formats.euroc.calibration import read_camera_sensor, read_imu_sensor
from slamcli.formats.euroc.source import mav_folder
from slamcli.geometry.se3 import inverse


def _rows(m: np.ndarray) -> list[list[float]]:
    return [[float(v) for v in row] for row in m]


def write_kalibr(folder: Path, out: Path, imu_placed: bool = True) -> tuple[Path, Path]:
    """``camchain-imucam.yaml`` (``T_cam_imu`` per camera; with ``imu_placed`` False a camera
    chain of ``T_cn_cnm1`` alone) and ``imu.yaml`` for ``folder``'s cameras and IMU."""
    mav = mav_folder(folder)
    imu = read_imu_sensor(mav / "imu0" / "sensor.yaml")
    chain: dict[str, dict] = {}
    previous = None
    for name in ("cam0", "cam1"):
        if not (mav / name / "sensor.yaml").is_file():
            break
        cam = read_camera_sensor(mav / name / "sensor.yaml")
        c = cam.camera
        imu_from_cam = inverse(imu.body_from_sensor) @ cam.body_from_sensor
        entry: dict = {
            "camera_model": "pinhole",
            "intrinsics": [c.fx, c.fy, c.cx, c.cy],
            "distortion_model": "radtan" if cam.model == "radial-tangential" else "equidistant",
            "distortion_coeffs": list(cam.coefficients),
            "resolution": [c.width, c.height],
            "rostopic": f"/{name}/image_raw",
            "timeshift_cam_imu": 0.0,
        }
        if imu_placed:
            entry["T_cam_imu"] = _rows(inverse(imu_from_cam))
        if previous is not None:
            entry["T_cn_cnm1"] = _rows(inverse(cam.body_from_sensor) @ previous)
            entry["cam_overlaps"] = [0]
        previous = cam.body_from_sensor
        chain[name] = entry
    out.mkdir(parents=True, exist_ok=True)
    camchain = out / ("camchain-imucam.yaml" if imu_placed else "camchain.yaml")
    camchain.write_text(yaml.safe_dump(chain, default_flow_style=None))
    imu_file = out / "imu.yaml"
    noise = imu.noise()
    imu_file.write_text(
        yaml.safe_dump(
            {**noise, "update_rate": float(imu.rate_hz), "rostopic": "/imu0"},
            default_flow_style=None,
        )
    )
    return camchain, imu_file
