"""2-D lidar SLAM (see :mod:`slamcli.pipelines.lidar.slam`)."""

from slamcli.pipelines.lidar.config import LidarConfig
from slamcli.pipelines.lidar.slam import LidarSlam

__all__ = ["LidarConfig", "LidarSlam"]
