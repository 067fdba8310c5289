"""slamcli: offline, batch SLAM from recorded robot and camera logs.

The library is usable without the command line: open a source with
:func:`slamcli.formats.open_source`, evaluate trajectories with :mod:`slamcli.evaluation`,
and read or write trajectories with :mod:`slamcli.formats.trajectory`.
"""

import logging

from slamcli.errors import SlamcliError
from slamcli.types import (
    ImageFrame,
    ImuFrame,
    LandmarkFrame,
    OccupancyGrid,
    OdometryFrame,
    PinholeCamera,
    RgbdFrame,
    SlamResult,
    Trajectory,
    TriangleMesh,
)

__version__ = "0.1.0"

__all__ = [
    "ImageFrame",
    "ImuFrame",
    "LandmarkFrame",
    "OccupancyGrid",
    "OdometryFrame",
    "PinholeCamera",
    "RgbdFrame",
    "SlamResult",
    "SlamcliError",
    "Trajectory",
    "TriangleMesh",
    "__version__",
]

logging.getLogger(__name__).addHandler(logging.NullHandler())
