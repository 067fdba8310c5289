"""The source registry is lazy: importing one format module, or the plan command, loads no
source module, and sniffing loads only the source that matches."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from slamcli.errors import UnknownFormatError
from slamcli.formats import SNIFFERS, SOURCES, source_class

REPO = Path(__file__).resolve().parents[1]
HEAVY = ("mcap", "cv2", "open3d", "rosbags", "trimesh", "matplotlib", "pycolmap")
SOURCE_MODULES = sorted({target.partition(":")[0] for target in SOURCES.values()})


def _loaded_after(code: str) -> set[str]:
    """The modules a fresh interpreter holds after running ``code``."""
    probe = f"{code}\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))"
    out = subprocess.run(
        [sys.executable, "-c", probe], cwd=REPO, capture_output=True, text=True, check=True
    )
    return set(json.loads(out.stdout.splitlines()[-1]))


@pytest.mark.parametrize(
    "module", ["slamcli.formats", "slamcli.formats.occupancy", "slamcli.cli.plan"]
)
def test_importing_a_format_loads_no_source(module: str) -> None:
    loaded = _loaded_after(f"import {module}")
    assert not {m.split(".")[0] for m in loaded} & set(HEAVY)
    assert not loaded & set(SOURCE_MODULES)


def test_sniffing_loads_only_the_matching_source() -> None:
    landmarks = REPO / "sample_data" / "landmarks"
    loaded = _loaded_after(
        f"from slamcli.formats import open_source\nopen_source({str(landmarks)!r}).close()"
    )
    assert "slamcli.formats.landmarks" in loaded
    assert not loaded & {"slamcli.formats.mcap.source", "slamcli.formats.tum_rgbd", "mcap"}


def test_every_format_has_a_class_and_a_sniffer() -> None:
    assert list(SNIFFERS) == list(SOURCES)
    for name in SOURCES:
        cls = source_class(name)
        assert cls.format_name == name
        assert cls.sniff.__doc__
    with pytest.raises(UnknownFormatError, match="unknown format 'nope'"):
        source_class("nope")
