"""SLAM pipelines. Each consumes frames through ``process(frame)`` and returns a
:class:`~slamcli.types.SlamResult` from ``finish()``; none prints or touches files."""

from __future__ import annotations

from typing import Any

PIPELINES: dict[str, str] = {
    "odometry": "slamcli.pipelines.odometry:RgbdOdometry",
    "dense": "slamcli.pipelines.dense:DenseSlam",
    "ekf": "slamcli.pipelines.ekf:EkfSlam",
}
"""Pipeline classes by name, as ``module:Class`` so heavy modules load only when used."""


def get_pipeline(name: str) -> Any:
    """The pipeline class registered under ``name``."""
    import importlib

    from slamcli.errors import ConfigError

    if name not in PIPELINES:
        raise ConfigError(
            f"unknown pipeline {name!r}", hint=f"choose one of {', '.join(PIPELINES)}"
        )
    module, _, cls = PIPELINES[name].partition(":")
    return getattr(importlib.import_module(module), cls)
