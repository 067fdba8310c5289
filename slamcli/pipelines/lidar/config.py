"""Settings of the lidar pipeline."""

from __future__ import annotations

from dataclasses import dataclass

from slamcli.config import setting


@dataclass(frozen=True)
class LidarConfig:
    """Settings of :class:`~slamcli.pipelines.lidar.LidarSlam`. Lengths in metres, angles in
    degrees, times in seconds.

    Attributes:
        resolution_m: cell side of the submaps and the final map.
        max_range_m: readings farther than this are not used.
        voxel_m: cell of the voxel filter that evens out a scan's points before matching.
        field_sigma_m: width of the likelihood field scans are matched on.
        motion_prior: where a scan's first guess comes from: ``auto`` (odometry when the log
            has it, else constant velocity), ``odometry``, ``constant_velocity`` or ``none``
            (the last pose).
        search_window_m, search_window_deg: half-width of the correlative search around the
            guess.
        min_match_score: a match scoring less (mean likelihood, 0 to 1) is not trusted: the
            scan keeps its guess and is counted.
        motion_min_m, motion_min_deg, motion_max_s: a scan becomes a node of the graph (and is
            inserted into the submaps) when the pose moved this far or this much time passed
            since the last node.
        scans_per_submap: nodes inserted into a submap before it is finished (a new submap
            starts halfway, so each node is in two).
        loop_search_m: a finished submap is searched for the current node when one of its
            nodes lies this close (plus the window's growth).
        loop_window_m, loop_window_deg: half-width of the loop search window just after a loop
            closed; it grows by ``loop_growth`` (fraction of the distance travelled, and
            degrees per metre) until the next one, up to ``loop_window_max_m`` and
            ``loop_window_max_deg``.
        loop_min_score: the loop search's match score threshold.
        loop_min_fit: fraction of the scan's points that must lie on the submap's walls
            after refinement (geometric verification).
        loop_every_m: distance travelled between two loop searches.
        loop_min_gap: nodes between the current node and a submap's last node before that
            submap is searched.
        edge_sigma_m, edge_sigma_deg: uncertainty of a scan-matched edge between consecutive
            nodes; ``loop_sigma_m``, ``loop_sigma_deg`` of a loop edge.
        loop_kernel: robust kernel on loop edges (``huber``, ``cauchy``, ...).
    """

    resolution_m: float = setting(0.05, gt=0.0, max=1.0, unit="m")
    max_range_m: float = setting(30.0, gt=0.0, unit="m")
    voxel_m: float = setting(0.1, min=0.0, unit="m")
    field_sigma_m: float = setting(0.07, gt=0.0, unit="m")
    motion_prior: str = setting("auto", choices=("auto", "odometry", "constant_velocity", "none"))
    search_window_m: float = setting(0.4, gt=0.0, max=5.0, unit="m")
    search_window_deg: float = setting(20.0, gt=0.0, max=90.0, unit="deg")
    min_match_score: float = setting(0.3, min=0.0, max=1.0)
    motion_min_m: float = setting(0.1, min=0.0, unit="m")
    motion_min_deg: float = setting(5.0, min=0.0, unit="deg")
    motion_max_s: float = setting(5.0, gt=0.0, unit="s")
    scans_per_submap: int = setting(40, min=2)
    loop_search_m: float = setting(4.0, min=0.0, unit="m")
    loop_window_m: float = setting(1.0, gt=0.0, unit="m")
    loop_window_deg: float = setting(10.0, gt=0.0, unit="deg")
    loop_growth: float = setting(0.05, min=0.0)
    loop_window_max_m: float = setting(5.0, gt=0.0, unit="m")
    loop_window_max_deg: float = setting(30.0, gt=0.0, max=180.0, unit="deg")
    loop_min_score: float = setting(0.55, min=0.0, max=1.0)
    loop_min_fit: float = setting(0.6, min=0.0, max=1.0)
    loop_every_m: float = setting(0.5, min=0.0, unit="m")
    loop_min_gap: int = setting(10, min=1)
    edge_sigma_m: float = setting(0.05, gt=0.0, unit="m")
    edge_sigma_deg: float = setting(1.0, gt=0.0, unit="deg")
    loop_sigma_m: float = setting(0.05, gt=0.0, unit="m")
    loop_sigma_deg: float = setting(1.0, gt=0.0, unit="deg")
    loop_kernel: str = setting("huber", choices=("none", "huber", "cauchy", "dcs", "tukey"))
