"""Path planning on occupancy grids: exact grid search (:mod:`slamcli.planning.search`).

From a map to a driven path (:func:`slamcli.planning.planner.plan`): free space and the
clearance cost (:mod:`~slamcli.planning.costmap`), shortcutting and corner rounding
(:mod:`~slamcli.planning.smooth`), a speed profile (:mod:`~slamcli.planning.trajectory`), a
pure-pursuit simulation (:mod:`~slamcli.planning.tracker`) with dynamic obstacles
(:mod:`~slamcli.planning.obstacles`), and the output files (:mod:`~slamcli.planning.output`,
:mod:`~slamcli.planning.plot`).
"""
