"""MuJoCo simulation: Panda scenes, parts, thread coupling, control and the environments."""

from itskill.sim.gl import configure_gl

GL_BACKEND = configure_gl()
"""The offscreen backend chosen at import (None if neither EGL nor OSMesa is installed)."""
