"""Settings of the visual pipeline."""

from __future__ import annotations

from dataclasses import dataclass

from slamcli.config import setting
from slamcli.errors import ConfigError


@dataclass(frozen=True)
class VisualConfig:
    """Settings of :class:`VisualSlam`. Lengths in metres, angles in degrees."""

    mode: str = setting(
        "auto",
        help="rgbd uses a depth image, stereo a rectified stereo pair, mono colour only (a map "
        "without metric scale, scored after Sim(3) alignment); auto picks stereo for stereo "
        "input, rgbd when the input has depth, mono otherwise",
        choices=("auto", "rgbd", "stereo", "mono"),
    )
    max_features: int = setting(
        1000, help="ORB features per frame (RGB-D and monocular)", min=100, max=20000
    )
    stereo_max_features: int = setting(
        2000,
        help="ORB features per image of a stereo pair (ORB-SLAM's KITTI setting: stereo keeps "
        "only the keypoints matched in the right image as near points)",
        min=100,
        max=20000,
    )
    levels: int = setting(8, help="ORB pyramid levels", min=1, max=12)
    scale_factor: float = setting(1.2, help="ORB pyramid scale between levels", gt=1.0, max=2.0)
    fast_threshold: int = setting(
        12, help="FAST corner threshold; corners are ranked and spread afterwards", min=1, max=100
    )
    depth_min_m: float = setting(
        0.1,
        help="depth readings nearer than this are ignored (stereo: the disparity searched "
        "stops there)",
        unit="m",
        min=0.0,
    )
    depth_max_m: float = setting(
        4.0, help="depth readings further than this are ignored", unit="m", gt=0.0
    )
    depth_baseline_m: float = setting(
        0.16,
        help="RGB-D: a keypoint's depth is weighed as the disparity of a stereo pair with this "
        "baseline (ORB-SLAM uses 0.08 for a Kinect); larger trusts depth more",
        unit="m",
        gt=0.0,
        max=1.0,
    )
    stereo_far_baselines: float = setting(
        40.0,
        help="stereo: keypoints further than this many baselines are far points (their depth "
        "is too coarse to trust; they are triangulated from motion instead, as ORB-SLAM's "
        "ThDepth)",
        gt=1.0,
        max=1000.0,
    )
    stereo_min_near: int = setting(
        100,
        help="stereo: when fewer keypoints than this lie nearer than stereo_far_baselines, the "
        "nearest far ones keep their depth too, up to this many (as ORB-SLAM's keyframes take "
        "at least 100 points from stereo), so that a short-baseline rig in a large space still "
        "starts and holds its scale; 0 never keeps a far point's depth",
        min=0,
    )
    keyframe_track_ratio: float = setting(
        0.75,
        help="a keyframe is made when a frame tracks fewer than this share of its reference "
        "keyframe's points (monocular: at least 0.9)",
        gt=0.0,
        max=1.0,
    )
    keyframe_max_frames: int = setting(
        10, help="a keyframe is made at least this often (frames)", min=1
    )
    keyframe_max_seconds: float = setting(
        0.5,
        help="a keyframe is made at least this often (seconds of the input's stamps), so that "
        "a slow camera (10 Hz) keeps keyframes as close as a fast one; whichever of this and "
        "keyframe_max_frames comes first",
        unit="s",
        gt=0.0,
    )
    local_window: int = setting(
        10, help="covisible keyframes optimised by local bundle adjustment", min=1, max=100
    )
    ba_iterations: int = setting(10, help="iterations of each local bundle adjustment", min=1)
    min_tracked: int = setting(
        30, help="least map points a tracked frame must match after the local-map search", min=6
    )
    pnp_threshold_px: float = setting(
        4.0, help="RANSAC inlier threshold of PnP (relocalisation, loops)", unit="px", gt=0.0
    )
    loop_closure: bool = setting(True, help="detect and close loops")
    vocabulary: str = setting(
        "default",
        help="bag-of-words vocabulary for loop closure and relocalisation: 'default' (shipped "
        "with slamcli, see slamcli/data/VOCABULARY.md) or a file made by 'slamcli vocab train'",
    )
    loop_consistency: int = setting(
        3,
        help="consecutive keyframes a loop candidate must be recognised from before it is verified",
        min=1,
    )
    loop_min_inliers: int = setting(
        40, help="least matched points of a verified loop after the guided search", min=10
    )
    loop_max_scale_change: float = setting(
        2.0,
        help="monocular: the largest scale change a loop may correct, as a factor either way; "
        "a loop needing more is refused, and the run records the doubt",
        gt=1.0,
    )
    loop_max_rotation_deg: float = setting(
        30.0,
        help="the largest rotation a loop may correct at the keyframe that closes it; a loop "
        "needing more is refused, and the run records the doubt",
        unit="deg",
        gt=0.0,
    )
    loop_max_drift: float = setting(
        0.3,
        help="the largest translation a loop may correct, as a share of the path the keyframes "
        "travelled since the place was seen; a loop needing more is refused, and the run "
        "records the doubt",
        gt=0.0,
    )
    global_ba: bool = setting(
        True, help="global bundle adjustment after a loop closure and at the end"
    )
    final_pose_refinement: bool = setting(
        True,
        help="re-estimate every frame's pose against the final map (else frames keep the "
        "pose tracked online, moved with their keyframe)",
    )
    new_map_after_lost: int = setting(3, help="lost frames after which a new map is started", min=1)
    mono_min_parallax_deg: float = setting(
        1.0, help="monocular initialisation: least median parallax", unit="deg", gt=0.0
    )
    mono_min_points: int = setting(
        50, help="monocular initialisation: least triangulated points", min=8
    )
    imu: bool = setting(
        True,
        help="with an IMU in the input, run visual-inertial: the map becomes metric (also "
        "monocular) and gravity-aligned, z up, once the IMU is initialised; false ignores the IMU",
    )
    imu_init_s: float = setting(
        2.0,
        help="the IMU is initialised once the map's keyframes span this long, and retried at "
        "each keyframe until the motion determines the scale and gravity",
        unit="s",
        gt=0.0,
    )
    imu_refine_s: float = setting(
        3.0,
        help="this long after the initialisation, the whole map is adjusted again with its "
        "inertial terms (scale, gravity and biases refined over the longer stretch)",
        unit="s",
        gt=0.0,
    )
    imu_max_blind_s: float = setting(
        5.0,
        help="an initialised map poses frames on the IMU alone for at most this long when "
        "vision fails (dark or blurred images); after that a new map is started",
        unit="s",
        gt=0.0,
    )
    threads: int = setting(
        2,
        help="1 does everything on one core; 2 decodes and extracts features of the next "
        "frames, and runs local bundle adjustment, beside tracking (same results either way)",
        choices=(1, 2),
    )
    side_process_after_s: float = setting(
        0.5,
        help="threads=2: local bundle adjustment runs beside tracking, on a second process, "
        "once the adjustments run in place have taken this long (about what starting that "
        "process costs, so a short run never pays for it); 0 starts it at the first "
        "adjustment (same results either way)",
        unit="s",
        min=0.0,
    )
    seed: int = setting(0, help="seeds every RANSAC", min=0, max=2**31 - 1)

    def __post_init__(self) -> None:
        if self.depth_min_m >= self.depth_max_m:
            raise ConfigError(
                f"visual.depth_min_m: expected less than visual.depth_max_m "
                f"({self.depth_max_m}), got {self.depth_min_m!r}",
                hint="set visual.depth_min_m below visual.depth_max_m",
            )
