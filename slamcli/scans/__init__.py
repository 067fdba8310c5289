"""2-D scan geometry: scans to points, probability grids, scan matching and loop search.

``points`` turns a :class:`~slamcli.types.ScanFrame` into points; ``grid`` holds the
probability grids scans are inserted into (submaps and the final map), ray cast free along each
beam and occupied at its end; ``matching`` aligns a scan to a grid (a correlative search over a
likelihood field, then a continuous refinement); ``loops`` finds a scan in a finished submap over
a wide window (branch and bound over a max-pooled pyramid). No I/O; numpy and OpenCV only.
"""
