"""Fast CPU rendering of robosuite scenes: one GL context, light meshes, cached background.

See docs/rendering.md for the pipeline, the measured cost and what was traded.
"""

from crowdteleop.sim.fastrender.glcontext import SharedGLContext
from crowdteleop.sim.fastrender.renderer import FastSceneRenderer
from crowdteleop.sim.fastrender.simplify import SimplifiedMesh, SimplifyParams

__all__ = ["FastSceneRenderer", "SharedGLContext", "SimplifiedMesh", "SimplifyParams"]
