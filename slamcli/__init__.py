"""slamcli: offline, batch SLAM from recorded robot and camera logs.

The library is usable without the command line: open a source with
:func:`slamcli.formats.open_source`, evaluate trajectories with :mod:`slamcli.evaluation`,
and read or write trajectories with :mod:`slamcli.formats.trajectory`.
"""

import logging
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

__all__ = [
    "ImageFrame",
    "ImuFrame",
    "LandmarkFrame",
    "LandmarkMap",
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

if TYPE_CHECKING:
    from slamcli.errors import SlamcliError
    from slamcli.types import (
        ImageFrame,
        ImuFrame,
        LandmarkFrame,
        LandmarkMap,
        OccupancyGrid,
        OdometryFrame,
        PinholeCamera,
        RgbdFrame,
        SlamResult,
        Trajectory,
        TriangleMesh,
    )


def __getattr__(name: str) -> Any:
    # Re-exports load on first use, so the CLI starts without importing numpy.
    if name == "SlamcliError":
        from slamcli.errors import SlamcliError

        return SlamcliError
    if name in __all__:
        from slamcli import types

        return getattr(types, name)
    raise AttributeError(f"module 'slamcli' has no attribute {name!r}")


logging.getLogger(__name__).addHandler(logging.NullHandler())
