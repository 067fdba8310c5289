"""EuRoC / ASL folders: rectified stereo pairs and IMU samples (``source.py``), read with the
calibration of their ``sensor.yaml`` files (``calibration.py``)."""

from slamcli.formats.euroc.calibration import (
    CameraSensor,
    ImuSensor,
    StereoRectification,
    read_camera_sensor,
    read_imu_sensor,
    read_sensor_yaml,
    rectify_stereo,
)
from slamcli.formats.euroc.source import (
    FRAME_KINDS,
    PAIR_MAX_DT_S,
    EurocSource,
    ImageCsv,
    mav_folder,
    read_image_csv,
    read_imu_csv,
)

__all__ = [
    "FRAME_KINDS",
    "PAIR_MAX_DT_S",
    "CameraSensor",
    "EurocSource",
    "ImageCsv",
    "ImuSensor",
    "StereoRectification",
    "mav_folder",
    "read_camera_sensor",
    "read_image_csv",
    "read_imu_csv",
    "read_imu_sensor",
    "read_sensor_yaml",
    "rectify_stereo",
]
