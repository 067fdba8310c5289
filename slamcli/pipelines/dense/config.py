"""Settings of the dense pipeline."""

from __future__ import annotations

from dataclasses import dataclass

from slamcli.config import setting
from slamcli.errors import ConfigError

_METHODS = ("hybrid", "point_to_plane", "intensity")


@dataclass(frozen=True)
class DenseConfig:
    """Settings of :class:`DenseSlam`. Lengths in metres, angles in degrees."""

    voxel_size_m: float = setting(0.01, help="TSDF voxel edge", unit="m", gt=0.0, max=0.5)
    block_resolution: int = setting(
        16,
        help="voxels per block edge; a block holds block_resolution**3 voxels",
        choices=(8, 16, 32),
    )
    block_count: int = setting(
        0,
        help="initial voxel-block capacity; 0 sizes it from the first integrated frame. The "
        "volume grows with the scene either way, so this only saves early regrowth",
        unit="blocks",
        min=0,
    )
    block_growth: float = setting(
        1.5,
        help="when a frame's blocks would not fit, the capacity grows to this multiple of the "
        "blocks then needed; a block of 16**3 voxels holds 80 kB",
        min=1.1,
        max=4.0,
    )
    depth_min_m: float = setting(
        0.1, help="depth readings nearer than this are ignored", unit="m", min=0.0
    )
    depth_max_m: float = setting(
        3.0, help="depth readings further than this are ignored", unit="m", gt=0.0
    )
    sdf_trunc_voxels: float = setting(
        8.0, help="TSDF truncation distance", unit="voxels", min=1.0, max=64.0
    )
    min_valid_depth_fraction: float = setting(
        0.2,
        help="a frame with a smaller share of valid depth pixels is tracked if possible but "
        "never integrated",
        min=0.0,
        max=1.0,
    )
    track_downsample: int = setting(
        2,
        help="the frame-to-model registration runs on images shrunk by this factor (ray "
        "casting costs grow with the pixel count); never below 160 pixels wide, where the "
        "coarse pyramid levels would have too few pixels",
        choices=(1, 2, 4),
    )
    odometry_method: str = setting(
        "point_to_plane",
        help="loss of the frame-to-model refinement: photometric + geometric, geometric only, "
        "or photometric only",
        choices=_METHODS,
    )
    odometry_iterations: tuple[int, ...] = setting(
        (6, 4, 2), help="odometry iterations per pyramid level, coarse to fine", min=1, max=100
    )
    depth_outlier_m: float = setting(
        0.07,
        help="odometry correspondences further apart than this are rejected",
        unit="m",
        gt=0.0,
    )
    min_fitness: float = setting(
        0.1,
        help="least share of pixels with a correspondence for a trusted registration",
        min=0.0,
        max=1.0,
    )
    max_jump_m: float = setting(
        0.15, help="largest deviation from the constant-velocity prediction", unit="m", gt=0.0
    )
    max_jump_deg: float = setting(
        15.0,
        help="largest turn away from the constant-velocity prediction",
        unit="deg",
        gt=0.0,
        max=180.0,
    )
    max_seed_disagreement_m: float = setting(
        0.05,
        help="largest offset between the feature seed and the dense refinement before the "
        "refinement is distrusted",
        unit="m",
        gt=0.0,
    )
    max_seed_disagreement_deg: float = setting(
        4.0,
        help="largest rotation between the feature seed and the dense refinement before the "
        "refinement is distrusted",
        unit="deg",
        gt=0.0,
        max=180.0,
    )
    orb_features: int = setting(1000, help="ORB keypoints per frame", min=1, max=100000)
    match_ratio: float = setting(0.8, help="Lowe ratio for ORB descriptor matches", gt=0.0, max=1.0)
    pnp_reprojection_px: float = setting(
        3.0, help="RANSAC inlier threshold of PnP", unit="px", gt=0.0
    )
    pnp_iterations: int = setting(200, help="RANSAC iterations of PnP", min=1)
    pnp_min_inliers: int = setting(
        25, help="least PnP inliers for a feature pose; EPnP needs 4", min=4
    )
    relocalise_keyframes: int = setting(
        8, help="how many of the latest keyframes relocalisation tries", min=1
    )
    keyframe_every: int = setting(
        10,
        help="frames between keyframes at most; with front_end=visual no keyframe is made "
        "within keyframe_min_m and keyframe_min_deg of one from loop_min_frames or more "
        "before, so revisits add none",
        min=1,
    )
    keyframe_min_m: float = setting(
        0.1, help="motion since the last keyframe that makes a new one", unit="m", gt=0.0
    )
    keyframe_min_deg: float = setting(
        10.0, help="turn since the last keyframe that makes a new one", unit="deg", gt=0.0
    )
    loop_min_frames: int = setting(
        45, help="frames between two keyframes before they may close a loop", min=1
    )
    loop_max_distance_m: float = setting(
        1.0, help="largest distance between the poses of loop candidates", unit="m", min=0.0
    )
    loop_max_angle_deg: float = setting(
        45.0,
        help="largest angle between the poses of loop candidates",
        unit="deg",
        min=0.0,
        max=180.0,
    )
    loop_min_match_ratio: float = setting(
        0.08,
        help="least share of ORB descriptors with a ratio-test match for a loop candidate",
        min=0.0,
        max=1.0,
    )
    loop_max_candidates: int = setting(
        2,
        help="loop candidates verified per keyframe, best appearance first; 0 closes no loops",
        min=0,
    )
    loop_min_inliers: int = setting(30, help="least PnP inliers for a loop", min=4)
    loop_min_fitness: float = setting(
        0.3, help="least RGB-D odometry fitness for a loop", min=0.0, max=1.0
    )
    loop_max_disagreement_m: float = setting(
        0.02,
        help="largest offset between the PnP and the dense estimate of a loop's relative pose",
        unit="m",
        min=0.0,
    )
    loop_max_disagreement_deg: float = setting(
        1.5,
        help="largest rotation between the PnP and the dense estimate of a loop's relative pose",
        unit="deg",
        min=0.0,
        max=180.0,
    )
    pose_graph_prune: float = setting(
        0.25, help="edge-prune threshold of the line process", min=0.0, max=1.0
    )
    pose_graph_max_correspondence_m: float = setting(
        0.03, help="correspondence distance of the global optimisation", unit="m", gt=0.0
    )
    pose_graph_loop_preference: float = setting(
        0.1, help="weight of loop edges against odometry edges", min=0.0
    )
    reintegrate_min_shift_m: float = setting(
        0.002,
        help="the volume is rebuilt when the optimisation moves a keyframe further than this",
        unit="m",
        min=0.0,
    )
    reintegrate_min_shift_deg: float = setting(
        0.1,
        help="the volume is rebuilt when the optimisation turns a keyframe further than this",
        unit="deg",
        min=0.0,
    )
    mesh_weight_threshold: float = setting(
        3.0,
        help="least integration weight of voxels in the mesh and points; after a rebuild from "
        "the keyframes it shrinks with their share of the frames, to one at least",
        min=0.0,
    )
    undistort: bool = setting(
        True,
        help="remap frames whose camera has lens distortion onto the same pinhole (colour "
        "bilinear, depth nearest-neighbour) before anything else; the volume, ray casts and "
        "odometry all assume a pinhole camera",
        choices=(True, False),
    )
    seed: int = setting(0, help="seeds OpenCV's RNG (PnP RANSAC)", min=0, max=2**31 - 1)
    front_end: str = setting(
        "visual",
        help="what gives each frame's pose before the frame-to-model refinement: the visual "
        "pipeline's tracker (its local map, motion model and local bundle adjustment; loops "
        "closed by its place recognition and GTSAM pose graph), or ORB PnP against the "
        "previous frame with the dense pipeline's own loop closure",
        choices=("visual", "frames"),
    )
    model_weight: float = setting(
        0.25,
        help="with front_end=visual, the share of the frame-to-model refinement in each pose: 0 "
        "keeps the visual tracker's pose, 1 takes the refined one",
        min=0.0,
        max=1.0,
    )
    threads: int = setting(
        2,
        help="1 does everything on one core; 2 decodes the next frames and extracts their "
        "features beside tracking and fusion (same results either way)",
        choices=(1, 2),
    )

    def __post_init__(self) -> None:
        # Single values are range-checked where they are read (load_config); what remains is
        # what one field's range cannot say.
        if self.depth_min_m >= self.depth_max_m:
            raise ConfigError(
                f"dense.depth_min_m: expected less than dense.depth_max_m "
                f"({self.depth_max_m}), got {self.depth_min_m!r}",
                hint="set dense.depth_min_m below dense.depth_max_m",
            )
        if not self.odometry_iterations:
            raise ConfigError(
                "dense.odometry_iterations: expected at least one pyramid level, got []",
                hint="for example --set dense.odometry_iterations=[6, 4, 2]",
            )
