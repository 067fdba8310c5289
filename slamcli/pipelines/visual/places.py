"""Place recognition for the visual pipeline: every keyframe's bag of words in a database,
queried to relocalise a lost frame and to find loops and maps to merge."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.pipelines.visual.atlas import Keyframe, SparseMap


class Places:
    """The keyframe database of a run, over the vocabulary ``vocabulary`` ('default': the
    shipped one, else a file made by ``slamcli vocab train``), loaded at the first keyframe."""

    def __init__(self, vocabulary: str, smap: SparseMap) -> None:
        self._name = vocabulary
        self._map = smap
        self._db: Any = None

    @property
    def db(self) -> Any:
        """The :class:`~slamcli.vision.vocabulary.KeyframeDatabase`."""
        if self._db is None:
            from slamcli.vision.vocabulary import (
                KeyframeDatabase,
                default_vocabulary,
                load_vocabulary,
            )

            voc = default_vocabulary() if self._name == "default" else load_vocabulary(self._name)
            self._db = KeyframeDatabase(voc)
        return self._db

    def index(self, kf: Keyframe) -> None:
        """Give ``kf`` its bag of words and add it to the database."""
        db = self.db
        kf.bow = db.vocabulary.bow(kf.descriptors)
        db.add(kf.id, kf.bow)

    def remove(self, kf_id: int) -> None:
        """Take a culled keyframe out of the database."""
        if self._db is not None:
            self._db.remove(kf_id)

    def candidates(
        self, descriptors: NDArray[np.uint8], map_id: int | None, limit: int
    ) -> list[tuple[int, float]]:
        """(keyframe id, score) of the live keyframes (of map ``map_id``, or any) most like an
        image with ORB ``descriptors``, best first, at most ``limit``."""
        db = self.db
        bow = db.vocabulary.bow(descriptors)
        out = []
        for kf_id, score in db.query(bow):
            kf = self._map.keyframes[kf_id]
            if kf.culled or (map_id is not None and kf.map_id != map_id):
                continue
            out.append((kf_id, score))
            if len(out) >= limit:
                break
        return out
