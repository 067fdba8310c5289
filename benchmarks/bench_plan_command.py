"""Wall time of the whole `slamcli plan` command on the shared building floors, stage by stage.

Each map (stata_basement: 1730 x 1300 cells, origin yaw 3.14 rad; building_31: 693 x 648
cells) gets a start and a goal far apart in its largest free region for a 0.2 m robot (the
farthest apart of seeded random pairs of its cells). `slamcli plan MAP --start --goal --out TMP
--force` then runs REPEATS times as a fresh process; printed are the median wall time of the
process and the median of each stage in plan.json's `timings_ms` (`total` is the command's own
count from its process start to plan.json). Beside them, measured in the same run: the median
wall time of `python -c "import numpy"`, the floor any numpy command stands on.

Usage: python benchmarks/bench_plan_command.py [MAPS_DIR] [--repeats 5] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DEFAULT = Path(__file__).resolve().parents[2] / "shared/data/maps"
MAPS = ("stata_basement", "building_31")
ROBOT_RADIUS_M = 0.2


def far_apart(map_file: Path, seed: int, pairs: int = 200) -> tuple[str, str]:
    """``x,y`` texts of two cell centres of the largest free region, far apart."""
    import cv2

    from slamcli.formats.occupancy import cell_to_world
    from slamcli.planning.costmap import build_costmap
    from slamcli.planning.planner import load_map

    grid, _ = load_map(map_file)
    free = (~build_costmap(grid, ROBOT_RADIUS_M).blocked).astype(np.uint8)
    # 4-connected regions: the cells the planner's graph connects.
    count, labels = cv2.connectedComponents(free, connectivity=4)
    sizes = np.bincount(labels.ravel(), minlength=count)
    sizes[0] = 0
    cells = np.argwhere(labels == int(np.argmax(sizes)))
    rng = np.random.default_rng(seed)
    a = cells[rng.integers(len(cells), size=pairs)]
    b = cells[rng.integers(len(cells), size=pairs)]
    k = int(np.argmax(np.hypot(*(a - b).T)))
    start, goal = cell_to_world(grid, np.stack((a[k], b[k])))
    return f"{start[0]:.4f},{start[1]:.4f}", f"{goal[0]:.4f},{goal[1]:.4f}"


def wall_ms(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    return (time.perf_counter() - t0) * 1000.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("maps", nargs="?", type=Path, default=DEFAULT)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    numpy_ms = statistics.median(
        wall_ms([sys.executable, "-c", "import numpy"]) for _ in range(args.repeats)
    )
    print(f'python -c "import numpy": {numpy_ms:.0f} ms (median of {args.repeats})')
    rows: list[str] = []
    stage_names: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in MAPS:
            map_file = args.maps / f"{name}.yaml"
            start, goal = far_apart(map_file, args.seed)
            out = Path(tmp) / name
            cmd = [sys.executable, "-m", "slamcli", "plan", str(map_file)]
            cmd += [f"--start={start}", f"--goal={goal}", "--out", str(out), "--force"]
            walls: list[float] = []
            stages: dict[str, list[float]] = {}
            for _ in range(args.repeats):
                walls.append(wall_ms(cmd))
                # The stages as plan.json lists them, in its order.
                timings = json.loads((out / "plan.json").read_text())["timings_ms"]
                for s, ms in timings.items():
                    stages.setdefault(s, []).append(ms)
            stage_names = stage_names or list(stages)
            row = f"{name:<16}{statistics.median(walls):>7.0f}"
            row += "".join(
                f"{statistics.median(stages.get(s, [float('nan')])):>11.1f}" for s in stage_names
            )
            rows += [row, f"{'':<16}start {start}, goal {goal}"]
    print("\nmedian ms per run of `slamcli plan`")
    print(f"{'map':<16}{'wall':>7}" + "".join(f"{s:>11}" for s in stage_names))
    print("\n".join(rows))


if __name__ == "__main__":
    main()
