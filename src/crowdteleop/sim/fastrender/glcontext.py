"""One OpenGL context per process, shared by every fast renderer in it.

`mujoco.Renderer` makes a GL context and an `MjrContext` (every mesh and texture uploaded again)
per instance, i.e. per resolution: +360 MiB per resolution measured on Lift. Rendering never
needs more than one GL context: each render model keeps one `MjrContext` (meshes, textures, its
own offscreen framebuffer) inside it, and a frame of any size is a viewport of that framebuffer.

The context is created on first use and freed when the last renderer lets go. GL contexts are
bound to one thread at a time, so every use goes through `current()`, which takes a process-wide
lock and makes the context current on the calling thread.

Process-wide state is unavoidable here (the whole point is one per process); it is confined to
two class attributes of `SharedGLContext`, guarded by a lock.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import ClassVar

import mujoco

from crowdteleop.gl import render_backend_error

# The context's own (window) framebuffer is never drawn into: renderers draw into MjrContext
# offscreen buffers. Keep it tiny.
WINDOW_SIZE = 16


class SharedGLContext:
    """Reference-counted owner of the process's GL context; get it with `acquire`."""

    _lock: ClassVar[threading.RLock] = threading.RLock()
    _instance: ClassVar[SharedGLContext | None] = None

    def __init__(self, context: mujoco.GLContext) -> None:
        self._context = context
        self._users = 0

    @classmethod
    def acquire(cls) -> SharedGLContext:
        """The shared context, created if no renderer holds it; pair with `release`."""
        with cls._lock:
            if cls._instance is None:
                try:
                    context = mujoco.GLContext(WINDOW_SIZE, WINDOW_SIZE)
                except Exception as exc:  # each GL library fails in its own way
                    raise render_backend_error(exc) from exc
                cls._instance = cls(context)
            cls._instance._users += 1
            return cls._instance

    @classmethod
    def peek(cls) -> SharedGLContext | None:
        """The live shared context, if any (for diagnostics and tests)."""
        return cls._instance

    @property
    def users(self) -> int:
        return self._users

    @contextmanager
    def current(self) -> Iterator[None]:
        """Hold the process's GL lock with this context current on the calling thread.

        Made current on every entry: other code (a `mujoco.Renderer`, robosuite's viewer) may
        have made its own context current on this thread in between.
        """
        with self._lock:
            if self._context is None:
                raise RuntimeError("the shared GL context was released")
            try:
                self._context.make_current()
            except Exception as exc:
                raise render_backend_error(exc) from exc
            yield

    def release(self) -> None:
        """Drop one use; the last one frees the GL context."""
        cls = type(self)
        with cls._lock:
            self._users -= 1
            if self._users > 0:
                return
            if cls._instance is self:
                cls._instance = None
            context, self._context = self._context, None
            if context is not None:
                context.free()
