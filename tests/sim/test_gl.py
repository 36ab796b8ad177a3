"""The OpenGL backend MuJoCo is started with: the user's if it can work, else one installed."""

from __future__ import annotations

import ctypes.util
import os
import platform

import pytest

from itskill.sim.gl import configure_gl


@pytest.fixture
def only_egl(monkeypatch):
    monkeypatch.setattr(
        ctypes.util, "find_library", lambda name: "libEGL.so.1" if name == "EGL" else None
    )
    monkeypatch.delenv("MUJOCO_GL", raising=False)


@pytest.mark.parametrize("named", ["glfw", "EGL", " glx", "disable", "off"])
def test_a_value_mujoco_takes_is_kept(only_egl, monkeypatch, named: str) -> None:
    # As MuJoCo reads it: any case, spaces around; GL turned off is the user's choice too.
    monkeypatch.setattr(platform, "system", lambda: "Linux")
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
