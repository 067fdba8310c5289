"""ROS bags as inputs: ROS 1 ``.bag`` files and ROS 2 bag folders.

- :mod:`~slamcli.formats.rosbag.source`: the sources (the MCAP source over the bag readers);
- :mod:`~slamcli.formats.rosbag.ros1_log`: ROS 1 bags through their index or by their records;
- :mod:`~slamcli.formats.rosbag.ros1`: the ROS 1 record format and the record walker;
- :mod:`~slamcli.formats.rosbag.ros2_log`: ROS 2 bags (sqlite3 or MCAP storage);
- :mod:`~slamcli.formats.rosbag.health`: the bag health report, one channel per topic.
"""
