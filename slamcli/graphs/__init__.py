"""Pose graphs and factor graphs on GTSAM: loop closure for the visual pipeline, graph SLAM,
multi-robot merging and ``slamcli graph optimize``. GTSAM is imported inside the functions that
need it, so importing these modules is cheap."""
