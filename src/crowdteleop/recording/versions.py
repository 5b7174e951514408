"""Versions a demonstration depends on: recorded with it, so a dataset says what made it."""

from __future__ import annotations

import functools
import importlib.metadata
import platform

SCHEMA_VERSION = 1  # of the dataset built by `crowdteleop dataset build` (docs/dataset.md)


def runtime_versions() -> dict[str, str]:
    """crowdteleop, robosuite, mujoco, numpy and Python versions of this process."""
    return dict(_versions())


@functools.cache
def _versions() -> tuple[tuple[str, str], ...]:
    versions = [("python", platform.python_version())]
    for package in ("crowdteleop", "robosuite", "mujoco", "numpy", "h5py"):
        try:
            versions.append((package, importlib.metadata.version(package)))
        except importlib.metadata.PackageNotFoundError:
            versions.append((package, "unknown"))
    return tuple(versions)
