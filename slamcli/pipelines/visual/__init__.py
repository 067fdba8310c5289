"""Feature-based visual SLAM: :class:`VisualSlam` (the pipeline ``visual``) and its settings.

The package follows ORB-SLAM's threads of work, one module each: :mod:`.tracking`,
:mod:`.local_mapping` (with :mod:`.bundle`), :mod:`.loop_closing` (with :mod:`.places`), the
maps in :mod:`.atlas`, monocular start-up in :mod:`.initializer`, and :mod:`.slam`, which runs
them frame by frame.
"""

from slamcli.pipelines.visual.config import VisualConfig
from slamcli.pipelines.visual.slam import VisualSlam

__all__ = ["VisualConfig", "VisualSlam"]
