"""The OpenGL backend MuJoCo is started with: the user's if it can work, else one installed."""

from __future__ import annotations

import ctypes.util
import os

import pytest

from itskill.sim.gl import configure_gl


@pytest.fixture
def only_egl(monkeypatch):
    monkeypatch.setattr(
        ctypes.util, "find_library", lambda name: "libEGL.so.1" if name == "EGL" else None
    )
    monkeypatch.delenv("MUJOCO_GL", raising=False)


def test_a_backend_the_user_names_and_has_is_kept(only_egl, monkeypatch) -> None:
    monkeypatch.setenv("MUJOCO_GL", "glfw")
    assert configure_gl() == "glfw"


@pytest.mark.parametrize(
    ("named", "why"),
    [("bogus", "MuJoCo knows egl, osmesa, glfw"), ("osmesa", "apt-get install libosmesa6")],
)
def test_a_backend_mujoco_cannot_use_is_dropped_with_a_warning(
    only_egl, monkeypatch, named: str, why: str
) -> None:
    # MuJoCo failed on it at import: every command, rendering or not, ended in a traceback.
    monkeypatch.setenv("MUJOCO_GL", named)
    with pytest.warns(UserWarning, match=why):
        assert configure_gl() == "egl"
    assert os.environ["MUJOCO_GL"] == "egl"
