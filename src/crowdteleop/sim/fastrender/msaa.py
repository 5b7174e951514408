"""Multisampled colour for the background, drawn once, in a framebuffer that lives for one draw.

robosuite's picture is rendered with 4x MSAA (MuJoCo's default ``offsamples``); without it every
edge is a staircase, and edges are where nearly all of the remaining difference to robosuite's
picture sits. Per frame MSAA doubles llvmpipe's time (8.4 vs 4.2 ms for the moving pass
measured at 320x240), so frames are drawn without it; but the static background is drawn once
per camera, so it can afford it: table, walls and floor edges then match robosuite's pixels
exactly.

The render model's `MjrContext` is made with ``offsamples=0`` (so every frame is cheap), hence
a multisampled target of our own: a framebuffer with multisampled colour and depth-stencil
renderbuffers (stencil: MuJoCo draws reflections through it), resolved into a plain one and read
back, then deleted, so it holds no memory between background draws. MuJoCo's `mjr_render` draws
into whatever framebuffer is bound (it only rebinds its own for shadow maps, and the compositor
only runs on scenes without shadows). Depth for compositing still comes from MuJoCo's own
buffer, the same path as the moving layer's depth, so the two compare exactly.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import mujoco
import numpy as np
import numpy.typing as npt

log = logging.getLogger(__name__)


def draw_multisampled(
    draw: Callable[[], None],
    context: mujoco.MjrContext,
    width: int,
    height: int,
    samples: int,
) -> npt.NDArray[np.uint8] | None:
    """Run ``draw`` (an `mjr_render`) into a ``samples``x MSAA target; RGB, bottom row first.

    None when the GL cannot do it (the caller keeps its single-sampled picture).
    """
    try:
        from OpenGL import GL  # PyOpenGL, a dependency of mujoco; same platform as MuJoCo's
    except ImportError:  # pragma: no cover - mujoco depends on PyOpenGL
        return None
    frame_buffers: list[int] = []
    render_buffers: list[int] = []
    try:
        samples = min(samples, int(GL.glGetIntegerv(GL.GL_MAX_SAMPLES)))
        if samples < 2:
            return None
        color_format, depth_format = _formats(GL, context)
        multisampled, resolved = (int(x) for x in GL.glGenFramebuffers(2))
        frame_buffers += [multisampled, resolved]
        color, depth, color_resolved = (int(x) for x in GL.glGenRenderbuffers(3))
        render_buffers += [color, depth, color_resolved]
        for buffer, fmt, attachment, target, n in (
            (color, color_format, GL.GL_COLOR_ATTACHMENT0, multisampled, samples),
            (depth, depth_format, GL.GL_DEPTH_STENCIL_ATTACHMENT, multisampled, samples),
            (color_resolved, color_format, GL.GL_COLOR_ATTACHMENT0, resolved, 0),
        ):
            GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, buffer)
            GL.glRenderbufferStorageMultisample(GL.GL_RENDERBUFFER, n, fmt, width, height)
            GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, target)
            GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, attachment, GL.GL_RENDERBUFFER, buffer)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, multisampled)
        if GL.glCheckFramebufferStatus(GL.GL_FRAMEBUFFER) != GL.GL_FRAMEBUFFER_COMPLETE:
            return None
        GL.glDrawBuffer(GL.GL_COLOR_ATTACHMENT0)
        draw()
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, multisampled)
        GL.glReadBuffer(GL.GL_COLOR_ATTACHMENT0)
        GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, resolved)
        GL.glDrawBuffer(GL.GL_COLOR_ATTACHMENT0)
        GL.glBlitFramebuffer(
            0, 0, width, height, 0, 0, width, height, GL.GL_COLOR_BUFFER_BIT, GL.GL_NEAREST
        )
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, resolved)
        GL.glReadBuffer(GL.GL_COLOR_ATTACHMENT0)
        alignment = int(GL.glGetIntegerv(GL.GL_PACK_ALIGNMENT))
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)  # rows of 3 * width bytes, as numpy lays them
        rgb = np.empty((height, width, 3), dtype=np.uint8)
        GL.glReadPixels(0, 0, width, height, GL.GL_RGB, GL.GL_UNSIGNED_BYTE, rgb)
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, alignment)
        return rgb
    except Exception as exc:  # any GL shortfall: fall back to the single-sampled background
        log.warning("multisampled background unavailable (%s); using the plain one", exc)
        return None
    finally:
        if frame_buffers:
            GL.glDeleteFramebuffers(len(frame_buffers), frame_buffers)
        if render_buffers:
            GL.glDeleteRenderbuffers(len(render_buffers), render_buffers)
        mujoco.mjr_restoreBuffer(context)


def _formats(gl: Any, context: mujoco.MjrContext) -> tuple[int, int]:
    """MuJoCo's own colour and depth-stencil formats, so the picture matches its MSAA exactly."""
    formats = []
    for buffer in (context.offColor, context.offDepthStencil):
        gl.glBindRenderbuffer(gl.GL_RENDERBUFFER, buffer)
        query = gl.GL_RENDERBUFFER_INTERNAL_FORMAT
        formats.append(int(gl.glGetRenderbufferParameteriv(gl.GL_RENDERBUFFER, query)))
    return formats[0], formats[1]
