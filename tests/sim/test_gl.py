"""The OpenGL backend MuJoCo is started with: the user's if it can work, else one installed."""

from __future__ import annotations

import ctypes.util
import os
import platform

import pytest

from itskill.sim.gl import configure_gl, gl_help


@pytest.fixture
def only_egl(monkeypatch):
    monkeypatch.setattr(
        ctypes.util, "find_library", lambda name: "libEGL.so.1" if name == "EGL" else None
    )
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.setattr(platform, "system", lambda: "Linux")


@pytest.mark.parametrize("named", ["glfw", "EGL", " glx", "disable", "off"])
def test_a_value_mujoco_takes_is_kept(only_egl, monkeypatch, named: str) -> None:
    # As MuJoCo reads it: any case, spaces around; GL turned off is the user's choice too.
    monkeypatch.setenv("MUJOCO_GL", named)
    assert configure_gl() == named and os.environ["MUJOCO_GL"] == named


@pytest.mark.parametrize(
    ("named", "why"),
    [("bogus", "MuJoCo takes disable, "), ("osmesa", "apt-get install libosmesa6")],
)
def test_a_backend_mujoco_cannot_use_is_dropped_with_a_warning(
    only_egl, monkeypatch, named: str, why: str
) -> None:
    # MuJoCo failed on it at import: every command, rendering or not, ended in a traceback.
    monkeypatch.setenv("MUJOCO_GL", named)
    with pytest.warns(UserWarning, match=why):
        assert configure_gl() == "egl"
    assert os.environ["MUJOCO_GL"] == "egl"


def test_elsewhere_than_linux_no_linux_backend_is_chosen(only_egl, monkeypatch) -> None:
    # MuJoCo takes neither EGL nor OSMesa on Windows or macOS: it refused itskill's own choice.
    monkeypatch.setattr(platform, "system", lambda: "Windows")
    assert configure_gl() is None and "MUJOCO_GL" not in os.environ


def test_rendering_with_opengl_turned_off_says_to_turn_it_on() -> None:
    assert gl_help("off").endswith("MUJOCO_GL='off' turns it off: unset it.")
