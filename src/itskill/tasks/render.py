"""Offscreen rendering of task episodes to MP4 with ``mujoco.Renderer``.

The OpenGL backend is chosen when ``itskill.sim`` is imported (see :mod:`itskill.sim.gl`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import imageio.v2 as imageio
import mujoco
import numpy as np

from itskill.files import replaced_whole
from itskill.sim import GL_BACKEND
from itskill.sim.gl import gl_help
from itskill.sim.scene import offscreen_renderer
from itskill.tasks import make_batch_env
from itskill.tasks.evaluate import Policy, PolicyFactory, make_policy
from itskill.tasks.spec import TaskSpec

CAMERAS = ("front", "closeup")
HOLD_S = 0.5
"""How long the last frame of each episode stays on screen, so the outcome can be seen."""


class RenderError(RuntimeError):
    """A video that cannot be made: no working OpenGL backend, or an unusable output path."""


def _renderer(model: mujoco.MjModel, width: int, height: int) -> mujoco.Renderer:
    try:
        return offscreen_renderer(model, width, height)
    except ValueError:
        raise  # a size below one pixel: the message says so
    except Exception as err:  # the GL stack fails with ImportError, AttributeError, FatalError...
        backend = os.environ.get("MUJOCO_GL")
        if backend != GL_BACKEND:
            backend = f"{backend} (mujoco was imported before itskill)"
        raise RenderError(f"{gl_help(backend)} Cause: {type(err).__name__}: {err}") from err


@dataclass(frozen=True)
class VideoResult:
    """A written video: where, how many frames, and each episode's success."""

    path: Path
    frames: int
    successes: tuple[bool, ...]


def check_video_path(out: str | Path) -> Path:
    """``out`` as a path a video can be written to; :class:`RenderError` for anything that is
    not a .mp4 file path (found out only after the rollout otherwise, as an encoder's cryptic
    error)."""
    out = Path(out)
    if out.suffix.lower() != ".mp4" or out.is_dir():
        raise RenderError(f"{out}: the video must be a .mp4 file path")
    return out


def record(
    spec: TaskSpec,
    policy: str | Path | Policy | PolicyFactory,
    out: str | Path,
    episodes: int = 1,
    seed: int = 0,
    camera: str = "front",
    width: int = 640,
    height: int = 480,
) -> VideoResult:
    """Roll out ``episodes`` episodes of ``spec`` with ``policy`` and write them to ``out`` (MP4).

    The episodes are the ones :func:`itskill.tasks.evaluate.evaluate` counts for the same seed
    with ``num_envs=1``.
    """
    if camera not in CAMERAS:
        raise ValueError(f"unknown camera {camera!r}; expected one of {CAMERAS}")
    out = check_video_path(out)
    env = make_batch_env(spec, num_envs=1, seed=seed, n_threads=1)
    fps = round(1 / env.sim.control_dt)
    renderer = None
    frames, successes = 0, []
    try:
        actor = make_policy(policy, spec, 1)
        renderer = _renderer(env.sim.model, width, height)

        def frame() -> np.ndarray:
            renderer.update_scene(env.sim.datas[0], camera=camera)
            return renderer.render()

        def write(image: np.ndarray, times: int = 1) -> None:
            nonlocal frames
            for _ in range(times):
                writer.append_data(image)
            frames += times

        # Once the policy and the renderer load: a refused policy leaves no empty folders. The
        # video replaces ``out`` only once whole: a Ctrl-C left a short clip in its place.
        with (
            replaced_whole(out, keep_suffix=True) as tmp,
            imageio.get_writer(tmp, fps=fps, codec="libx264", quality=7) as writer,
        ):
            for _ in range(episodes):
                env.reset()
                actor.reset()
                write(frame())
                # ``advance`` does not auto-reset, so the final state is filmed too.
                while True:
                    res = env.advance(actor(env.context()))
                    image = frame()
                    write(image)
                    if res.terminated[0] or res.truncated[0]:
                        break
                write(image, round(HOLD_S * fps))
                successes.append(bool(res.success[0]))
    finally:
        if renderer is not None:
            # OSMesa's context crashes at interpreter exit if it is left to the garbage collector.
            renderer.close()
        env.close()
    return VideoResult(out, frames, tuple(successes))
