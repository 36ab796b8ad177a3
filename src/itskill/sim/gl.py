"""Choose MuJoCo's offscreen OpenGL backend before ``mujoco`` is first imported.

MuJoCo reads ``MUJOCO_GL`` once, at import. ``itskill.sim`` calls :func:`configure_gl` when it is
imported, before any of its modules imports ``mujoco``: the user's ``MUJOCO_GL`` if set and
MuJoCo can use it, else EGL if its library is installed, else OSMesa. A program that imports
``mujoco`` before ``itskill`` should set ``MUJOCO_GL`` itself.
"""

from __future__ import annotations

import ctypes.util
import os
import platform
import warnings

GL_PACKAGES = {"egl": "libegl1 libgl1-mesa-dri", "osmesa": "libosmesa6"}
"""Debian/Ubuntu packages each headless backend needs."""
_LIBRARIES = {"egl": "EGL", "osmesa": "OSMesa"}
_OFF = ("disable", "disabled", "off", "false", "0")
"""The values of ``MUJOCO_GL`` that turn OpenGL off."""
_ACCEPTED = {
    "": (
        *_OFF,
        "enable",
        "enabled",
        "on",
        "true",
        "1",
        "glfw",
    ),
    "Linux": ("glx", "egl", "osmesa"),
    "Windows": ("wgl",),
    "Darwin": ("cgl",),
}
"""The values of ``MUJOCO_GL`` MuJoCo takes (lower-cased and stripped, as it reads them): on
every platform, then on each one's own."""


class GLSettingWarning(UserWarning):
    """A ``MUJOCO_GL`` value that itskill drops (an itskill warning: the commands print it as one
    line)."""


def configure_gl() -> str | None:
    """Set ``MUJOCO_GL`` (unless the user did) to the first installed headless backend.

    A ``MUJOCO_GL`` MuJoCo cannot use (a value it does not take, or EGL or OSMesa without its
    library) is dropped with a warning and the choice made as if it were unset: MuJoCo fails on
    it at import, which stopped every command, rendering or not, with a traceback. Returns the
    user's value or the backend chosen, or ``None`` where none was (neither EGL nor OSMesa
    installed, or not on Linux).
    """
    wanted = os.environ.get("MUJOCO_GL", "")
    value = wanted.strip().lower()
    if value:
        accepted = (*_ACCEPTED[""], *_ACCEPTED.get(platform.system(), ()))
        library = _LIBRARIES.get(value)
        if value in accepted and (library is None or ctypes.util.find_library(library)):
            return wanted
        why = (
            f"its library is not installed ('apt-get install {GL_PACKAGES[value]}')"
            if value in accepted
            else f"MuJoCo takes {', '.join(accepted)}"
        )
        warnings.warn(f"MUJOCO_GL={wanted!r} is ignored: {why}", GLSettingWarning, stacklevel=2)
        del os.environ["MUJOCO_GL"]
    if platform.system() != "Linux":
        return None  # EGL and OSMesa are Linux's; elsewhere MuJoCo chooses its own
    for backend, library in _LIBRARIES.items():
        if ctypes.util.find_library(library):
            os.environ["MUJOCO_GL"] = backend
            return backend
    return None


def gl_help(backend: str | None) -> str:
    """What to install or set when rendering with ``backend`` failed."""
    if backend is not None and backend.strip().lower() in _OFF:
        return (
            f"offscreen rendering needs OpenGL, and MUJOCO_GL={backend!r} turns it off: unset it."
        )
    installs = " or ".join(f"'apt-get install {pkgs}'" for pkgs in GL_PACKAGES.values())
    which = f"MUJOCO_GL={backend!r}" if backend else "no EGL or OSMesa library found"
    return (
        f"offscreen rendering needs OpenGL ({which}). Install a headless backend: {installs}; "
        "itskill picks it up unless MUJOCO_GL names another (set it before Python starts)."
    )
