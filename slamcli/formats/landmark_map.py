"""``landmarks.csv``: a planar landmark map with uncertainties.

Header ``id,x,y,cov_xx,cov_xy,cov_yy``; one row per landmark, metres and square metres, ids as
the log named them (or the filter's own numbering when correspondences were unknown). Rows are
sorted by id. Covariance columns are empty when the map has none.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slamcli.atomic import atomic_path
from slamcli.errors import FormatError
from slamcli.formats.text import iter_data_lines
from slamcli.types import LandmarkMap

HEADER = "id,x,y,cov_xx,cov_xy,cov_yy"


def write_landmarks_csv(path: str | Path, landmarks: LandmarkMap) -> Path:
    """Write ``landmarks`` atomically; returns the path."""
    p = Path(path)
    lines = [HEADER]
    for k in range(len(landmarks)):
        x, y = landmarks.xy[k]
        if landmarks.cov is not None:
            c = landmarks.cov[k]
            cov = f"{c[0, 0]:.9g},{c[0, 1]:.9g},{c[1, 1]:.9g}"
        else:
            cov = ",,"
        lines.append(f"{int(landmarks.ids[k])},{x:.6f},{y:.6f},{cov}")
    with atomic_path(p) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return p


def read_landmarks_csv(path: str | Path) -> LandmarkMap:
    """Read a ``landmarks.csv``; a bad row is a :class:`FormatError` naming its line."""
    p = Path(path)
    ids: list[int] = []
    xy: list[tuple[float, float]] = []
    covs: list[tuple[float, float, float] | None] = []
    for line_no, parts in iter_data_lines(p, delimiter=","):
        if parts[0].strip() == "id":
            continue
        if len(parts) not in (3, 6):
            raise FormatError(p, f"expected {HEADER}, got {len(parts)} fields", line=line_no)
        try:
            ids.append(int(parts[0]))
            xy.append((float(parts[1]), float(parts[2])))
            has_cov = len(parts) == 6 and all(v.strip() for v in parts[3:])
            covs.append(tuple(float(v) for v in parts[3:6]) if has_cov else None)  # type: ignore[arg-type]
        except ValueError as exc:
            raise FormatError(p, f"not a number ({exc})", line=line_no) from exc
    cov = None
    if covs and all(c is not None for c in covs):
        cov = np.array([[[c[0], c[1]], [c[1], c[2]]] for c in covs if c is not None])
    return LandmarkMap(
        np.asarray(ids, dtype=np.int64), np.asarray(xy, dtype=np.float64).reshape(-1, 2), cov
    )
