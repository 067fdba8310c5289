"""The vision layer shared by the visual and dense pipelines: ORB features, matching, absolute
pose, two-view geometry, bundle adjustment and place recognition. Numpy in, numpy out."""
