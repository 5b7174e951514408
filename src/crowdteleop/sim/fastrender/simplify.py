"""Simplified copies of visual meshes, bounded by a geometric error rather than a face count.

On the CPU, drawing cost follows triangle count (Sawyer's visual meshes hold ~285k triangles, most
of them invisible detail at streaming resolutions). A fixed ratio breaks some parts: the notes in
platform-notes.md saw the gripper base fall apart below ~10%, and we measured parts whose quadric
collapse at 10% moves the surface by 1-4 cm while others stay within 4 mm at 3%. So each mesh gets
the smallest ratio from a ladder whose two-sided Hausdorff distance to the original stays within
a tolerance (4 mm by default: ~0.6 px at 320x240 from robosuite's frontview, ~0.9 px at 480x360;
docs/rendering.md has the cost and fidelity of 2.5, 4 and 6 mm).

Steps per mesh: weld duplicate vertices by position (the robot OBJ files repeat each vertex once
per normal, which to a decimator looks like a cloud of disconnected triangles), quadric edge
collapse preserving topology and normal orientation, then the error check. The result is written
as plain OBJ (positions and triangles only: MuJoCo computes normals, keeping sharp creases) into
the cache, named by the hash of the source bytes and the parameters. A cache hit reads a header
line and never imports pymeshlab. Meshes no ratio can simplify within tolerance are recorded as
such (a ``.keep`` marker) so the search is not repeated either.
"""

from __future__ import annotations

import importlib.metadata
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from crowdteleop.sim.fastrender.cache import cache_dir, content_key, write_atomically

log = logging.getLogger(__name__)

ALGORITHM_VERSION = 1  # bump when the method changes: old cache entries then simply miss
HEADER = "# crowdteleop-simplified"
SUPPORTED_SUFFIXES = (".obj", ".stl")


@dataclass(frozen=True)
class SimplifyParams:
    """What decides a simplified mesh; part of every cache key."""

    tolerance_m: float = 0.008  # max two-sided Hausdorff distance, in metres after mesh scale
    ratios: tuple[float, ...] = (  # fractions of the faces kept, searched smallest first
        0.03, 0.04, 0.05, 0.06, 0.07, 0.08, 0.1, 0.12, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.7,
    )  # fmt: skip
    min_faces: int = 1000  # fewer faces: ~0.1 ms a frame at most, not worth an approximation


@dataclass(frozen=True)
class SimplifiedMesh:
    """Outcome for one source file: ``path`` is what the render model should load."""

    source: Path
    path: Path
    faces_before: int
    faces_after: int
    error_m: float
    from_cache: bool


def simplified_mesh(
    source: Path, scale: float = 1.0, params: SimplifyParams | None = None
) -> SimplifiedMesh:
    """The cached simplification of ``source``, building it on a miss.

    ``scale`` is the largest absolute component of the MJCF ``scale`` attribute: the tolerance is
    in world units, the file in its own.
    """
    params = params or SimplifyParams()
    directory = cache_dir("meshes")
    key = content_key(
        source, ALGORITHM_VERSION, _pymeshlab_version(), params, round(float(scale), 12)
    )
    target, keep = directory / f"{key}.obj", directory / f"{key}.keep"
    hit = _read_entry(source, target, keep)
    if hit is not None:
        return hit
    try:
        result = _build(source, abs(float(scale)) or 1.0, params)
    except (ImportError, OSError) as exc:  # pymeshlab missing or its shared libraries
        log.warning("cannot simplify %s (%s); drawing it at full detail", source.name, exc)
        return SimplifiedMesh(source, source, 0, 0, 0.0, from_cache=False)  # retried next run
    if result is None:
        write_atomically(keep, f"no ratio within {params.tolerance_m} m for {source}\n")
        return SimplifiedMesh(source, source, 0, 0, 0.0, from_cache=False)
    vertices, faces, faces_before, ratio, error = result
    write_atomically(target, _obj_text(vertices, faces, faces_before, ratio, error, source))
    log.info(
        "simplified %s: %d -> %d faces (ratio %.2f, %.2f mm)",
        source.name,
        faces_before,
        len(faces),
        ratio,
        error * 1e3,
    )
    return SimplifiedMesh(source, target, faces_before, len(faces), error, from_cache=False)


def _pymeshlab_version() -> str:
    """Part of the key (another version may decimate differently), read without importing it."""
    try:
        return importlib.metadata.version("pymeshlab")
    except importlib.metadata.PackageNotFoundError:
        return "absent"


def _read_entry(source: Path, target: Path, keep: Path) -> SimplifiedMesh | None:
    if target.exists():
        with target.open() as handle:
            fields = handle.readline().split()
        try:
            if " ".join(fields[:2]) != HEADER:
                raise ValueError(fields[:2])
            before, after, error = int(fields[2]), int(fields[3]), float(fields[5])
        except (IndexError, ValueError):
            return None  # not ours or truncated: rebuild
        return SimplifiedMesh(source, target, before, after, error, from_cache=True)
    if keep.exists():
        return SimplifiedMesh(source, source, 0, 0, 0.0, from_cache=True)
    return None


def _build(
    source: Path, scale: float, params: SimplifyParams
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int32], int, float, float] | None:
    """Smallest ratio of the ladder within tolerance: (vertices, faces, before, ratio, error).

    Binary search over the ladder (the error shrinks as the ratio grows, near enough): four or
    five decimations per mesh instead of up to fifteen.
    """
    import pymeshlab  # heavy (bundles Qt); only imported on a cache miss

    meshes = pymeshlab.MeshSet()
    meshes.load_new_mesh(str(source))
    meshes.meshing_remove_duplicate_vertices()  # weld by position
    meshes.meshing_remove_unreferenced_vertices()
    original = meshes.current_mesh_id()
    faces_before = meshes.current_mesh().face_number()
    tolerance = params.tolerance_m / scale
    best: tuple[npt.NDArray[np.float64], npt.NDArray[np.int32], int, float, float] | None = None
    low, high = 0, len(params.ratios) - 1
    while low <= high:
        middle = (low + high) // 2
        ratio = params.ratios[middle]
        meshes.set_current_mesh(original)
        meshes.generate_copy_of_current_mesh()
        copy = meshes.current_mesh_id()
        meshes.meshing_decimation_quadric_edge_collapse(
            targetfacenum=max(4, int(faces_before * ratio)),
            preservetopology=True,
            preservenormal=True,
            qualitythr=0.3,
            autoclean=True,
        )
        error = _hausdorff(meshes, pymeshlab, original, copy)
        if error <= tolerance:
            mesh = meshes.current_mesh()
            best = (
                mesh.vertex_matrix().copy(),
                mesh.face_matrix().copy(),
                faces_before,
                ratio,
                error * scale,
            )
            high = middle - 1
        else:
            low = middle + 1
        meshes.delete_current_mesh()
    return best


def _hausdorff(meshes: Any, pymeshlab: Any, first: int, second: int) -> float:
    """Largest distance either surface strays from the other, sampled on vertices and faces."""
    samples = max(20000, meshes.mesh(first).vertex_number())
    worst = 0.0
    for sampled, target in ((first, second), (second, first)):
        result = meshes.get_hausdorff_distance(
            sampledmesh=sampled,
            targetmesh=target,
            samplevert=True,
            sampleedge=False,
            sampleface=True,
            samplenum=samples,
            maxdist=pymeshlab.PercentageValue(100),  # count every distance, however large
        )
        worst = max(worst, float(result["max"]))
    return worst


def _obj_text(
    vertices: npt.NDArray[np.float64],
    faces: npt.NDArray[np.int32],
    faces_before: int,
    ratio: float,
    error: float,
    source: Path,
) -> str:
    """Plain OBJ: a header line MuJoCo ignores (our cache metadata), ``v`` and ``f`` lines."""
    lines = [
        f"{HEADER} {faces_before} {len(faces)} {ratio} {error:.6g} {source.name}",
        *(f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices),
        *(f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces),
    ]
    return "\n".join(lines) + "\n"
