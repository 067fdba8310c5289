"""Dense RGB-D SLAM: :class:`DenseSlam` (the pipeline ``dense``) and its settings.

:mod:`.slam` runs the stages frame by frame; :mod:`.front_ends` gives each frame its pose (the
visual tracker, or frame-to-frame features), :mod:`.tracking` registers frames against the
model, :mod:`.volume` is the TSDF volume and :mod:`.frames` prepares the images.
"""

from slamcli.pipelines.dense.config import DenseConfig
from slamcli.pipelines.dense.slam import DenseSlam

__all__ = ["DenseConfig", "DenseSlam"]
