"""Choose MuJoCo's offscreen OpenGL backend before ``mujoco`` is first imported.

MuJoCo reads ``MUJOCO_GL`` once, at import. ``itskill.sim`` calls :func:`configure_gl` when it is
imported, before any of its modules imports ``mujoco``: the user's ``MUJOCO_GL`` if set, else EGL
if its library is installed, else OSMesa. A program that imports ``mujoco`` before ``itskill``
should set ``MUJOCO_GL`` itself.
"""

from __future__ import annotations

import ctypes.util
import os

GL_PACKAGES = {"egl": "libegl1 libgl1-mesa-dri", "osmesa": "libosmesa6"}
"""Debian/Ubuntu packages each headless backend needs."""


def configure_gl() -> str | None:
    """Set ``MUJOCO_GL`` (unless the user did) to the first installed headless backend.

    Returns the backend in force, or ``None`` if neither EGL nor OSMesa is installed.
    """
    if os.environ.get("MUJOCO_GL"):
        return os.environ["MUJOCO_GL"]
    for backend, library in (("egl", "EGL"), ("osmesa", "OSMesa")):
        if ctypes.util.find_library(library):
            os.environ["MUJOCO_GL"] = backend
            return backend
    return None


def gl_help(backend: str | None) -> str:
    """What to install or set when rendering with ``backend`` failed."""
    installs = " or ".join(f"'apt-get install {pkgs}'" for pkgs in GL_PACKAGES.values())
    which = f"MUJOCO_GL={backend!r}" if backend else "no EGL or OSMesa library found"
    return (
        f"offscreen rendering needs OpenGL ({which}). Install a headless backend: {installs}; "
        "itskill picks it up unless MUJOCO_GL names another (set it before Python starts)."
    )
