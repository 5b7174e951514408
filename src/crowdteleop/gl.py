"""Choose MuJoCo's offscreen OpenGL backend before mujoco is imported.

MuJoCo reads ``MUJOCO_GL`` once, at import time, so this must run first. We pick ``egl`` where a
GPU driver is present and ``osmesa`` (Mesa's software rasterizer) otherwise; an explicit
``MUJOCO_GL`` from the user always wins.
"""

from __future__ import annotations

import ctypes.util
import glob
import os

from crowdteleop.errors import RenderBackendError

_PACKAGE_FOR_BACKEND = {
    "osmesa": "libosmesa6",
    "egl": "libegl1 (and your GPU vendor's EGL driver)",
    "glfw": "libglfw3 (and an X display)",
}


def _gpu_driver_present() -> bool:
    """A vendor EGL driver other than Mesa's software one, with a device node to drive."""
    vendor_files = glob.glob("/usr/share/glvnd/egl_vendor.d/*.json")
    has_vendor = any("mesa" not in os.path.basename(path).lower() for path in vendor_files)
    has_device = bool(glob.glob("/dev/nvidia[0-9]*")) or bool(glob.glob("/dev/dri/renderD*"))
    return has_vendor and has_device


def choose_gl_backend() -> str:
    """Set ``MUJOCO_GL`` (and PyOpenGL's platform to match) unless the user already did."""
    backend = os.environ.get("MUJOCO_GL")
    if not backend:
        if _gpu_driver_present():
            backend = "egl"
        elif ctypes.util.find_library("OSMesa"):
            backend = "osmesa"
        else:
            backend = "egl"  # Mesa's EGL also renders on the CPU (llvmpipe)
        os.environ["MUJOCO_GL"] = backend
    if backend in ("egl", "osmesa"):
        os.environ.setdefault("PYOPENGL_PLATFORM", backend)
    # Mesa's llvmpipe spreads each frame over worker threads: lower latency for one session,
    # but more CPU in all (thread hand-offs) when every core serves sessions. Render in the
    # calling thread unless told otherwise.
    os.environ.setdefault("LP_NUM_THREADS", "0")
    return backend


def _backend_mujoco_loaded() -> str | None:
    """The backend mujoco fixed when it was imported (it reads MUJOCO_GL only then)."""
    try:
        from mujoco import gl_context
    except ImportError:
        return None
    module: str = gl_context.GLContext.__module__
    return module.rsplit(".", 1)[-1]


def render_backend_error(cause: BaseException) -> RenderBackendError:
    """The error a user sees when no GL context can be made: the package to install, or the
    import order to fix when mujoco was loaded before crowdteleop chose its backend."""
    backend = os.environ.get("MUJOCO_GL", "?")
    loaded = _backend_mujoco_loaded()
    if loaded is not None and loaded != backend:
        return RenderBackendError(
            f"mujoco was imported with the {loaded!r} GL backend before crowdteleop chose "
            f"MUJOCO_GL={backend} ({cause}). Import crowdteleop before mujoco or robosuite, "
            "or set MUJOCO_GL in the environment before starting Python."
        )
    package = _PACKAGE_FOR_BACKEND.get(backend, "libosmesa6")
    return RenderBackendError(
        f"MuJoCo cannot render offscreen with MUJOCO_GL={backend} ({cause}). "
        f"Install the Debian package {package} (apt-get install -y {package.split()[0]}), "
        "or set MUJOCO_GL=osmesa (CPU) / MUJOCO_GL=egl (GPU) explicitly."
    )
