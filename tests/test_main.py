"""The ``itskill`` entry point: a Ctrl-C while the app loads ends the command quietly."""

from __future__ import annotations

import builtins

import pytest

from itskill.__main__ import main


def test_ctrl_c_while_the_app_loads_exits_130_without_a_traceback(monkeypatch, capsys) -> None:
    real_import = builtins.__import__

    def interrupted(name, *args, **kwargs):
        if name == "itskill.cli":
            raise KeyboardInterrupt
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", interrupted)
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 130
    assert capsys.readouterr().err == "interrupted\n"
