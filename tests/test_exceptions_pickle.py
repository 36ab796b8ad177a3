"""Every itskill error survives a pickle round trip, as it must to come back from a worker process.

The classes are found by importing every module of the package, so an error class added later is
checked without anyone listing it here.
"""

from __future__ import annotations

import importlib
import inspect
import pickle
import pkgutil
from typing import Any

import pytest

import itskill
from itskill.datafile import DataFileError
from itskill.rl.config import HyperparamError
from itskill.rl.train import RewardLoadError
from itskill.skills.store import UnknownSkillError
from itskill.tasks.evaluate import CheckpointError
from itskill.tasks.spec import UnknownTaskError


def _subclasses(cls: type[BaseException]) -> set[type[BaseException]]:
    direct = set(cls.__subclasses__())
    return direct.union(*(_subclasses(sub) for sub in direct))


def _itskill_errors() -> list[type[BaseException]]:
    for module in pkgutil.walk_packages(itskill.__path__, "itskill."):
        importlib.import_module(module.name)
    found = [c for c in _subclasses(BaseException) if c.__module__.startswith("itskill.")]
    return sorted(found, key=lambda c: f"{c.__module__}.{c.__qualname__}")


def _plausible(param: inspect.Parameter) -> Any:
    """A value of the parameter's annotated type (a string, a number or a list of names)."""
    annotation = str(param.annotation)
    if "list" in annotation or "Sequence" in annotation:
        return ["reach_nut_m12", "pick_nut_m12"]
    if "int" in annotation and "str" not in annotation:
        return 3
    return f"<{param.name}>"


def _construct(cls: type[BaseException]) -> BaseException:
    """``cls`` built with a value for every named positional parameter, optional ones included so
    that any state they set is checked too; a message alone where ``__init__`` is Exception's."""
    params = list(inspect.signature(cls.__init__).parameters.values())[1:]
    positional = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
    args = [_plausible(p) for p in params if p.kind in positional]
    return cls(*(args or ["something went wrong"]))


ERRORS = _itskill_errors()


def test_the_errors_found_include_those_with_several_arguments() -> None:
    # Guards the enumeration itself: an empty or partial list would pass the test below vacuously.
    wanted = {DataFileError, HyperparamError, RewardLoadError, CheckpointError, UnknownTaskError}
    assert wanted | {UnknownSkillError} <= set(ERRORS)


@pytest.mark.parametrize("cls", ERRORS, ids=lambda c: f"{c.__module__}.{c.__qualname__}")
def test_error_survives_a_pickle_round_trip(cls: type[BaseException]) -> None:
    err = _construct(cls)
    back = pickle.loads(pickle.dumps(err))
    assert type(back) is cls
    assert str(back) == str(err)
    assert vars(back) == vars(err)
