"""crowdteleop: crowdsourced robot teleoperation on simulated arms (after RoboTurk, CoRL 2018)."""

from crowdteleop.gl import choose_gl_backend

# MuJoCo and PyOpenGL read MUJOCO_GL / PYOPENGL_PLATFORM once, when first imported, and several
# of our dependencies (mink, robosuite) import mujoco. Choosing here, before any submodule can
# import them, is the only order that always works. A user's own MUJOCO_GL still wins.
choose_gl_backend()

__version__ = "0.1.0"
