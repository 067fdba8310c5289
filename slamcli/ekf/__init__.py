"""EKF landmark SLAM: the filter, data association and map management."""
