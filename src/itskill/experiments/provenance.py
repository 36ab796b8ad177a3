"""Where a result came from: the command line, the machine, the library versions, the code's
commit, the date.

Every experiment and ``itskill learn`` run records these next to its results, and the report
prints them in its header, so a figure can be traced to what produced it.
"""

from __future__ import annotations

import datetime as dt
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any

from itskill.files import check_shape, read_json, write_json


def command_line() -> str:
    """The command that is running, as a user could paste it again."""
    argv = list(sys.argv)
    if argv and Path(argv[0]).name in ("itskill", "__main__.py"):
        argv[0] = "itskill"
    return shlex.join(argv)


def cpu_model() -> str:
    """The CPU's model name (from /proc/cpuinfo on Linux, else what platform reports)."""
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        for line in cpuinfo.read_text(errors="replace").splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def code_commit(where: Path | None = None) -> str | None:
    """The git commit of the itskill checkout that is running (or of ``where``), ``+dirty`` if
    tracked files were modified; None for an installed package or where git is missing. The
    shipped skills are part of the checkout, so the commit also names the source checkpoints an
    experiment used."""
    package = where or Path(__file__).resolve().parent

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", "-C", str(package), *args], capture_output=True, text=True, timeout=10,
            check=True,
        ).stdout.strip()  # fmt: skip

    try:
        commit = git("rev-parse", "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):
        return None
    return commit + ("+dirty" if dirty else "")


def machine_facts() -> dict[str, Any]:
    """CPU count and model, OS, Python and the versions of the libraries results depend on."""
    import mujoco
    import numpy
    import stable_baselines3
    import torch

    import itskill

    return {
        "cpu_count": os.cpu_count(),
        "cpu_model": cpu_model(),
        "os": platform.platform(),
        "python": platform.python_version(),
        "itskill": itskill.__version__,
        "torch": torch.__version__,
        "mujoco": mujoco.__version__,
        "stable_baselines3": stable_baselines3.__version__,
        "numpy": numpy.__version__,
        "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "commit": code_commit(),
    }


def now() -> str:
    """The current time, ISO 8601 with the local offset."""
    return dt.datetime.now().astimezone().isoformat(timespec="seconds")


_SESSIONS = {
    "sessions?": [
        {
            "command": str,
            "started": str,
            "finished": (str, None),
            "wall_s": (float, None),
            "machine": dict,
            "status?": str,
        }
    ]
}
"""What ``provenance.json`` holds: a session per command that worked on the run."""


class Sessions:
    """The sessions (start, end, command, machine) of a resumable run, in ``provenance.json``."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.data: dict[str, Any] = read_json(self.path) if self.path.is_file() else {}
        # Read by every report and resume: an edited file is named, not a KeyError later.
        check_shape(self.path, self.data, _SESSIONS)
        self.data.setdefault("sessions", [])

    def start(self, **extra: Any) -> None:
        """Record a new session starting now."""
        self._t0 = dt.datetime.now().timestamp()
        self.data["sessions"].append(
            {"command": command_line(), "started": now(), "finished": None, "wall_s": None,
             "machine": machine_facts(), **extra}
        )  # fmt: skip
        write_json(self.path, self.data)

    def finish(self, **extra: Any) -> None:
        """Mark the current session finished (or interrupted: pass ``status=...``)."""
        session = self.data["sessions"][-1]
        session.update(finished=now(), wall_s=round(dt.datetime.now().timestamp() - self._t0, 1))
        session.update(extra)
        write_json(self.path, self.data)

    @property
    def wall_s(self) -> float:
        """Total wall time of the recorded sessions (an unfinished one counts as zero)."""
        return float(sum(s.get("wall_s") or 0.0 for s in self.data["sessions"]))
