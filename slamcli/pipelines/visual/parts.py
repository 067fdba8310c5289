"""What the parts of the visual pipeline (tracking, local mapping, loop closing,
initialisation) share: the settings, the camera rig, the atlas, the place database, and the
counts and stage times."""

from __future__ import annotations

from dataclasses import dataclass

from slamcli.pipelines.timing import Stats
from slamcli.pipelines.visual.atlas import Atlas, SparseMap
from slamcli.pipelines.visual.config import VisualConfig
from slamcli.pipelines.visual.frames import Rig
from slamcli.pipelines.visual.places import Places


@dataclass(frozen=True)
class Shared:
    """The objects every part of one run works on."""

    config: VisualConfig
    rig: Rig
    atlas: Atlas
    places: Places
    stats: Stats


class Part:
    """A part of the visual pipeline: the shared objects as attributes, and ``map``, the
    atlas's sparse map."""

    def __init__(self, shared: Shared) -> None:
        self.config = shared.config
        self.rig = shared.rig
        self.atlas = shared.atlas
        self.places = shared.places
        self.stats = shared.stats

    @property
    def map(self) -> SparseMap:
        return self.atlas.map
