"""What every itskill error needs to cross a process boundary.

A job run by a worker process (:mod:`itskill.executors`) reports its failure by pickling the
exception. Python pickles an exception as ``type(err)(*err.args)``, and ``err.args`` holds only
the formatted message, so an error whose constructor takes several arguments cannot be rebuilt:
the parent gets a broken pool instead of the one-line error. :class:`PicklableError` rebuilds it
from the arguments it was constructed with.
"""

from __future__ import annotations

import functools
from typing import Any


class PicklableError(Exception):
    """An exception that pickles with the arguments of its constructor, whatever its ``__init__``
    passes on to :class:`Exception`: list it first among the bases of an error class."""

    def __new__(cls, *args: Any, **kwargs: Any) -> PicklableError:
        self = super().__new__(cls, *args, **kwargs)
        self._init_args = (args, kwargs)
        return self

    def __reduce__(self) -> tuple[Any, ...]:
        args, kwargs = self._init_args
        rebuild = functools.partial(type(self), **kwargs) if kwargs else type(self)
        # The state carries what the constructor set and anything set on the error afterwards.
        return rebuild, args, self.__dict__


class FieldError(PicklableError, ValueError):
    """A configuration field's value that cannot be used: ``field`` names it, so a front end
    can point at its own name for it (a command-line flag, a file's key)."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(message)
        self.field = field
