"""The only way generated reward code runs: a static allowlist, a bare namespace, time and memory
limits, and checked outputs. The threat model is in ``docs/sandbox.md``.

Layers, each for a reason:

1. :func:`check_source` parses the code and walks every AST node against allowlists: node types,
   imports (``import numpy as np``, ``import math``, ``from math import ...``), builtin names,
   attributes of ``np``/``np.linalg``/``math`` and attributes of anything else (array, dict and
   list methods). No name or attribute may start with ``_`` (the way out of every Python sandbox
   goes through dunders). Constant-size memory bombs (``10**10**10``, ``"a" * 10**12``,
   ``np.ones(10**12)``, ``range(10**12)``, ``[0] * int(1e12)``) are refused here: sizes are
   folded from number literals through ``+ - * **`` and ``int``, ``round``, ``abs``,
   ``math.floor``/``ceil``/``trunc`` and numpy's scalar types and roundings (``np.int64(1e12)``);
   a size computed from the data is left to layer 4. String, bytes, void and object dtypes (an
   element of ``"U1000"`` is 4 kB) and format widths above :data:`MAX_FORMAT_WIDTH` (one C call
   builds the string, which no timeout interrupts) are refused too, and f-string format specs
   computed in place (``f"{x:{w}}"``), whose width cannot be read.
2. :func:`compile_reward` runs the module in a fresh namespace whose builtins are only the safe
   ones (no ``open``, ``eval``, ``getattr``, ``type``, ``__import__``...; ``import`` statements are
   served by a private importer that hands out numpy and math and nothing else, and numpy's own
   submodules to numpy, which imports some on first use).
3. Every call has a wall-clock timeout: ``signal.setitimer(ITIMER_REAL)`` in the main thread, a
   watchdog thread that raises :class:`SandboxTimeout` in the calling thread otherwise. The
   context handed to the code is read-only, so it cannot corrupt the simulator's arrays.
4. :func:`apply_process_limits` caps CPU time and address space (``RLIMIT_CPU``/``RLIMIT_AS``) of
   the worker process a candidate trains in; a memory bomb there ends in ``MemoryError``, caught
   and reported, instead of the host swapping.
5. Outputs are validated: ``total`` of shape (N,) and finite, components a dict of str to finite
   (N,) arrays.
"""

from __future__ import annotations

import ast
import builtins
import ctypes
import functools
import hashlib
import math
import operator
import re
import signal
import threading
import traceback
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from itskill.reward_contract import RewardOutputError, check_reward_output

FILENAME = "<reward>"


class SandboxViolation(ValueError):
    """Static rejection: the code uses something outside the allowlist (message names the line)."""


class SandboxTimeout(RuntimeError):
    """A call ran past its time limit."""


class SandboxError(RuntimeError):
    """The code raised at run time or returned something invalid (the message has the
    traceback tail)."""


@dataclass(frozen=True)
class SandboxConfig:
    """Limits for running generated code.

    ``call_timeout_s`` bounds one call (and running the module body); ``cpu_limit_s`` and
    ``memory_limit_mb`` are applied by :func:`apply_process_limits` to a whole worker process
    (None: no limit), so they must leave room for everything else that process does (training).
    """

    call_timeout_s: float = 2.0
    cpu_limit_s: int | None = None
    memory_limit_mb: int | None = None
    max_source_chars: int = 20000


# ------------------------------------------------------------------------------ allowlists
SAFE_BUILTINS = frozenset(
    {
        "abs", "all", "any", "bool", "dict", "divmod", "enumerate", "filter", "float", "int",
        "isinstance", "len", "list", "map", "max", "min", "range", "reversed", "round", "set",
        "slice", "sorted", "str", "sum", "tuple", "zip", "True", "False", "None",
        "ArithmeticError", "ValueError", "ZeroDivisionError",
    }
)  # fmt: skip
"""Builtins the code may name. Left out on purpose: open, eval, exec, compile, getattr, setattr,
delattr, globals, locals, vars, dir, type, object, super, __import__, input, print, breakpoint,
help, memoryview, bytearray, classmethod, staticmethod, property, id, hash, iter/next (generator
objects), format (its mini-language reaches attributes)."""

NUMPY_ALLOWED = frozenset(
    {
        "abs", "absolute", "add", "all", "allclose", "amax", "amin", "any", "arange", "arccos",
        "arccosh", "arcsin", "arcsinh", "arctan", "arctan2", "arctanh", "argmax", "argmin",
        "argsort", "around", "array", "asarray", "atleast_1d", "atleast_2d", "average",
        "broadcast_to", "cbrt", "ceil", "clip", "column_stack", "concatenate", "copy", "cos",
        "cosh", "count_nonzero", "cross", "cumprod", "cumsum", "deg2rad", "degrees", "diag",
        "diff", "digitize", "divide", "dot", "dstack", "e", "einsum", "empty_like", "equal", "exp",
        "exp2", "expand_dims", "expm1", "eye", "fabs", "flip", "float32", "float64", "floor",
        "floor_divide", "fmax", "fmin", "fmod", "full", "full_like", "greater", "greater_equal",
        "heaviside", "hstack", "hypot", "inf", "inner", "int32", "int64", "interp", "isclose",
        "isfinite", "isinf", "isnan", "less", "less_equal", "linalg", "linspace", "log", "log10",
        "log1p", "log2", "logaddexp", "logical_and", "logical_not", "logical_or", "logical_xor",
        "matmul", "max", "maximum", "mean", "median", "min", "minimum", "mod", "multiply", "nan",
        "nan_to_num", "nanmax", "nanmean", "nanmin", "nansum", "negative", "newaxis", "not_equal",
        "ones", "ones_like", "outer", "percentile", "pi", "power", "prod", "quantile",
        "rad2deg", "radians", "reciprocal", "remainder", "repeat", "reshape", "rint", "round",
        "searchsorted", "select", "sign", "sin", "sinc", "sinh", "sort", "sqrt", "square",
        "squeeze", "stack", "std", "subtract", "sum", "take", "take_along_axis", "tan", "tanh",
        "tensordot", "tile", "trace", "transpose", "tril", "triu", "trunc", "unwrap", "var",
        "vstack", "where", "zeros", "zeros_like", "bool_", "float16", "int8", "int16", "uint8",
    }
)  # fmt: skip
"""``np.X`` the code may use: math, reductions, array construction and dtypes. Not I/O (load,
save, fromfile, memmap, genfromtxt, DataSource), not buffers (frombuffer, ndarray, ctypeslib), not
submodules other than linalg (lib, testing, f2py, distutils, core, os, sys), not random."""

LINALG_ALLOWED = frozenset({"norm", "det", "inv", "solve", "pinv", "eigh", "eigvalsh"})

MATH_ALLOWED = frozenset(
    name for name in dir(math) if not name.startswith("_")
)  # ``math`` has only numeric functions and constants

METHOD_ALLOWED = frozenset(
    {
        # ndarray
        "T", "all", "any", "argmax", "argmin", "argsort", "astype", "clip", "conj", "copy",
        "cumprod", "cumsum", "dot", "dtype", "fill", "flatten", "imag", "item", "max", "mean",
        "min", "ndim", "nonzero", "prod", "ravel", "real", "repeat", "reshape", "round", "shape",
        "size", "sort", "squeeze", "std", "sum", "take", "tolist", "transpose", "var",
        # dict and list
        "append", "count", "extend", "get", "index", "items", "keys", "pop", "setdefault",
        "update", "values",
    }
)  # fmt: skip
"""Attributes of any other object (arrays, dicts, lists). Not tofile, dump, dumps, tobytes,
ctypes, data, base, flags, setflags, view, format, gi_frame, f_globals..."""

_ALLOWED_NODES = (
    ast.Module, ast.Expr, ast.Import, ast.ImportFrom, ast.alias, ast.FunctionDef, ast.arguments,
    ast.arg, ast.Return, ast.Assign, ast.AugAssign, ast.AnnAssign, ast.For, ast.While, ast.If,
    ast.Break, ast.Continue, ast.Pass, ast.Assert, ast.BinOp, ast.UnaryOp, ast.BoolOp,
    ast.Compare, ast.Call, ast.keyword, ast.IfExp, ast.NamedExpr, ast.Name, ast.Load, ast.Store,
    ast.Constant, ast.Attribute, ast.Subscript, ast.Slice, ast.Starred, ast.Tuple, ast.List,
    ast.Dict, ast.Set, ast.ListComp, ast.DictComp, ast.SetComp, ast.comprehension,
    ast.JoinedStr, ast.FormattedValue, ast.operator, ast.unaryop, ast.boolop, ast.cmpop,
    ast.expr_context,
)  # fmt: skip
"""Everything else is refused, notably: lambda (no use in a reward, and closures invite
introspection), generator expressions and yield (generator objects carry frames), class, try,
with, raise, global, nonlocal, del, async/await, match."""

_NODE_WHY = {
    ast.Lambda: "lambda is not allowed (define a function with def)",
    ast.GeneratorExp: "generator expressions are not allowed (use a list comprehension)",
    ast.Yield: "yield is not allowed",
    ast.YieldFrom: "yield is not allowed",
    ast.ClassDef: "class definitions are not allowed",
    ast.Try: "try is not allowed",
    ast.With: "with is not allowed",
    ast.Raise: "raise is not allowed",
    ast.Global: "global is not allowed",
    ast.Nonlocal: "nonlocal is not allowed",
    ast.Delete: "del is not allowed",
    ast.AsyncFunctionDef: "async is not allowed",
    ast.Await: "await is not allowed",
}

MAX_CONSTANT_ELEMENTS = 10**8
"""Largest constant size for a repeated sequence, a range or an array constructor."""
MAX_INT_BITS = 4096
"""Largest integer a constant power may produce."""
_SIZED_NUMPY = {"zeros", "ones", "full"}
"""Constructors whose first argument is the shape."""
_REPEATING_NUMPY = {"tile", "repeat"}
"""Functions whose first argument is repeated by the others."""
_LIKE_NUMPY = {"empty_like", "zeros_like", "ones_like", "full_like"}
_OTHER_SIZED_NUMPY = {"eye", "arange", "linspace", "broadcast_to"}
_PRODUCT_NUMPY = {"outer"}
"""Functions whose result holds the product of their two arguments' sizes."""
_SIZE_CHECKED = _SIZED_NUMPY | _REPEATING_NUMPY | _LIKE_NUMPY | _OTHER_SIZED_NUMPY | _PRODUCT_NUMPY
"""The numpy functions whose size :func:`_elements` reads from their arguments."""
MAX_FORMAT_WIDTH = 10_000
"""Largest constant width or precision in a format: ``f"{0:10000000000}"`` is a 10 GB string
made in one C call, which no timeout interrupts."""
_FLEXIBLE_DTYPES = re.compile(r"^[<>=|]?[USVaO]|^(str|bytes|object|void|str_|bytes_|object_)$")
"""The dtypes of strings, bytes, raw memory and Python objects, as ``dtype=`` or ``astype``
name them: no reward needs one, and their item size (``"U1000"``, 4 kB an element) multiplies
every size this module counts."""
_DTYPE_POSITION = {
    "zeros": 1, "ones": 1, "full": 2, "array": 1, "asarray": 1, "eye": 3, "arange": 3,
    "linspace": 5,
    "zeros_like": 1, "ones_like": 1, "empty_like": 1, "full_like": 2,
}  # fmt: skip
"""The position of ``dtype`` among the arguments of the numpy functions that take one."""
_TEXT_ARRAYS = "string, bytes, void and object arrays are not allowed (a reward is made of numbers)"
_FORMAT_NUMBER = re.compile(r"\d+")
_UNREAD_PERCENT = re.compile(r"(?<!%)(?:%%)*%(?:\([^)]*\(|[-#0 +]*\*|[-#0 +]*\d*\.\*)")
"""A ``%`` conversion whose width comes from the arguments (``%*d``) or whose mapping key holds
parentheses, which :data:`_PERCENT_SPEC` cannot read."""
_PERCENT_SPEC = re.compile(r"%%|%(?:\([^)]*\))?[-#0 +]*(\d*)(?:\.(\d*))?")
"""A ``%`` conversion's width and precision (after an optional mapping key); ``%%`` is a
literal percent sign, whose groups are empty."""


def _violation(node: ast.AST, what: str) -> SandboxViolation:
    return SandboxViolation(f"line {getattr(node, 'lineno', '?')}: {what}")


def _shown(value: int) -> str:
    """``value`` for a message: Python refuses to print an integer of over 4,300 digits."""
    return str(value) if value.bit_length() <= 64 else f"a {value.bit_length()}-bit number"


_FOLDED_OPS: dict[type[ast.operator], Callable[[Any, Any], Any]] = {
    ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Pow: operator.pow,
}  # fmt: skip
"""The operators folded (with an integer's bound when both sides are integers)."""
_FOLDED_MATH: dict[str, Callable[[Any], Any]] = {
    "floor": math.floor, "ceil": math.ceil, "trunc": math.trunc,
}  # fmt: skip
_FOLDED_BUILTINS: dict[str, Callable[[Any], Any]] = {
    "int": int, "round": round, "abs": abs, **_FOLDED_MATH,  # and ``from math import floor``
}  # fmt: skip
_FOLDED_NUMPY: dict[str, Callable[[Any], Any]] = {
    **dict.fromkeys(("int8", "int16", "int32", "int64", "uint8"), int),
    **dict.fromkeys(("float16", "float32", "float64"), float),
    **_FOLDED_MATH, **dict.fromkeys(("round", "around", "rint"), round),
    **dict.fromkeys(("abs", "absolute", "fabs"), abs),
}  # fmt: skip
"""Functions of one constant number folded too: ``np.zeros(int(1e11))`` and
``np.zeros(np.int64(1e11))`` are as obvious a size as ``np.zeros(10**11)``. Folded by name: a
reward that defines its own ``round`` is checked as if it used the builtin, and a bare ``floor``
as math's; math's functions imported under another name are not folded (what such a function
really computes is left to the process limits, as any computed size is). Numpy's are folded as
Python's: ``np.floor`` gives an int where numpy gives a float, and a narrow integer type does not
wrap (``np.int8(1e3)`` is 1000 here, -24 in numpy): the size checked is never smaller than the
size made."""


_T = TypeVar("_T")


def _once_per_node(fold: Callable[[ast.AST], _T]) -> Callable[[ast.AST], _T]:
    """``fold`` remembered on each node it is asked about. The checker asks about every node of
    a chain ``a * b * c * ...``, and each answer folds the chain below it: without this, cubic
    in the chain's length (20 s for a reward of a few hundred factors, in the host process)."""
    key = f"_sandbox_{fold.__name__}"

    @functools.wraps(fold)
    def once(node: ast.AST) -> _T:
        if key not in node.__dict__:
            node.__dict__[key] = fold(node)
        return node.__dict__[key]

    return once


@_once_per_node
def _const_number(node: ast.AST) -> int | float | None:
    """The value of a constant numeric expression (``10**10``, ``-3``, ``int(1e6) * 2``,
    ``math.ceil(2.5e11)``), refusing huge integers; None when it is not constant. A float that
    overflows or is not finite is None too: it cannot become a size."""
    if isinstance(node, ast.Constant):
        value = node.value
        if isinstance(value, int):
            return int(value)
        return value if isinstance(value, float) and math.isfinite(value) else None
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        number = _const_number(node.operand)
        return None if number is None else (-number if isinstance(node.op, ast.USub) else number)
    if isinstance(node, ast.BinOp):
        return _fold_binop(node)
    if isinstance(node, ast.Call) and len(node.args) == 1 and not node.keywords:
        func = node.func
        if isinstance(func, ast.Name):
            fold = _FOLDED_BUILTINS.get(func.id)
        elif isinstance(func, ast.Attribute) and _is_module(func.value, "math"):
            fold = _FOLDED_MATH.get(func.attr)
        elif isinstance(func, ast.Attribute) and _is_module(func.value, "np"):
            fold = _FOLDED_NUMPY.get(func.attr)
        else:
            fold = None
        number = None if fold is None else _const_number(node.args[0])
        if number is None:
            return None
        try:
            # Exact for a finite float (at most 1,024 bits) and a bounded integer alike.
            return fold(number)
        except OverflowError:  # float() of an integer past 1e308: no size either
            return None
    return None


def _fold_binop(node: ast.BinOp) -> int | float | None:
    """``left op right`` of two constant numbers (:func:`_const_number`)."""
    left, right = _const_number(node.left), _const_number(node.right)
    op = _FOLDED_OPS.get(type(node.op))
    if left is None or right is None or op is None:
        return None
    if isinstance(left, float) or isinstance(right, float):
        try:
            value = op(left, right)
        except (OverflowError, ZeroDivisionError):  # 10.0 ** 400, 10**400 * 1.0, 0.0 ** -1
            return None
        # A negative number to a fractional power is complex: no size either.
        return value if isinstance(value, float) and math.isfinite(value) else None
    if isinstance(node.op, ast.Pow):
        if right < 0:
            return None
        # Compared before the float product, which overflows for a huge exponent.
        if abs(left) > 1 and (right > MAX_INT_BITS or right * math.log2(abs(left)) > MAX_INT_BITS):
            raise _violation(node, f"constant power too large ({_shown(left)} ** {_shown(right)})")
        return left**right
    value = op(left, right)
    if value.bit_length() > MAX_INT_BITS:
        # Products of allowed powers grow without bound: 2**4000 * 2**4000 * ...
        raise _violation(node, f"constant too large ({_shown(value)})")
    return value


def _const_int(node: ast.AST) -> int | None:
    """The value of a constant integer expression (:func:`_const_number`); None for a float."""
    number = _const_number(node)
    return number if isinstance(number, int) else None


def _dims(node: ast.AST) -> list[ast.expr] | None:
    """The dimensions of a shape written as a tuple or list, repeated (``(10**5,) * 2``) or
    joined (``(n,) + (10**5,)``); None for any other expression, which is one number."""
    if isinstance(node, (ast.Tuple, ast.List)):
        return list(node.elts)
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        left, right = _dims(node.left), _dims(node.right)
        return None if left is None or right is None else left + right
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mult):
        for seq, count in ((node.left, node.right), (node.right, node.left)):
            dims, times = _dims(seq), _const_int(count)
            if dims is not None and times is not None:
                # numpy takes at most 64 dimensions, and 65 of 2 or more are past any limit:
                # the cap only keeps ``(1,) * 10**9`` from being unrolled here.
                return dims * min(max(times, 0), 65)
    return None


def _const_size(node: ast.AST) -> int | None:
    """Number of elements a constant size argument asks for: a number (a float too, as
    ``np.arange(1e12)`` takes) or a shape of them (:func:`_dims`)."""
    dims = _dims(node)
    if dims is None:
        dims = [node]
    numbers = [_const_number(dim) for dim in dims]
    sizes = [abs(int(number)) for number in numbers if number is not None]
    return math.prod(sizes) if len(sizes) == len(numbers) else None


@_once_per_node
def _elements(node: ast.AST) -> int | None:
    """How many elements an expression is known to hold before it runs: a literal sequence or
    string, a sequence repeated a constant number of times, or a numpy constructor, repetition or
    ``*_like`` of constant size. None when it depends on the data."""
    if isinstance(node, (ast.List, ast.Tuple)):
        return len(node.elts)
    if isinstance(node, ast.Constant) and isinstance(node.value, (str, bytes)):
        return len(node.value)
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mult):
        # Repetition of a literal sequence only: an array times a number keeps its size.
        for seq, count in ((node.left, node.right), (node.right, node.left)):
            if isinstance(seq, (ast.List, ast.Tuple, ast.Constant, ast.BinOp)):
                size, times = _elements(seq), _const_int(count)
                if size is not None and times is not None:
                    return size * abs(times)
        return None
    if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)):
        return None
    if not _is_module(node.func.value, "np"):
        return None
    name = node.func.attr

    def arg(index: int | None, *keywords: str) -> ast.expr | None:
        """The argument at ``index`` (None: a keyword-only one) or given by one of its
        ``keywords``, as numpy names it: a size passed either way is the same size."""
        if index is not None and index < len(node.args):
            return node.args[index]
        return next((k.value for k in node.keywords if k.arg in keywords), None)

    def size(index: int, *keywords: str) -> int | None:
        value = arg(index, *keywords)
        return None if value is None else _const_size(value)

    if name == "eye":
        rows = size(0, "N")
        given = arg(1, "M")
        # M=None is numpy's default: as many columns as rows.
        none = given is None or (isinstance(given, ast.Constant) and given.value is None)
        cols = rows if none else size(1, "M")
        return None if rows is None or cols is None else rows * cols
    if name in _SIZED_NUMPY:
        return size(0, "shape")
    if name == "arange":
        return _arange_length(arg(0, "start"), arg(1, "stop"), arg(2, "step"))
    if name == "linspace":
        return size(2, "num")
    if name in _REPEATING_NUMPY:
        # At least ``times`` elements whatever is repeated (it may be the data's).
        times = size(1, "repeats", "reps")
        inner = arg(0, "a", "A")
        return None if times is None else ((inner and _elements(inner)) or 1) * times
    if name in _LIKE_NUMPY:
        shape = arg(None, "shape")  # it replaces the prototype's shape
        if shape is not None:
            return _const_size(shape)
        inner = arg(0, "a", "prototype")
        return None if inner is None else _elements(inner)
    if name == "broadcast_to":
        return size(1, "shape")
    if name in _PRODUCT_NUMPY:
        first, second = arg(0, "a"), arg(1, "b")
        sizes = [None if x is None else _elements(x) for x in (first, second)]
        return None if None in sizes else math.prod(sizes)
    return None


def _arange_length(*given: ast.expr | None) -> int | None:
    """How many elements ``np.arange`` or ``range`` makes from its arguments ``(start, stop,
    step)`` as written (None where left out), a lone first argument being the stop; None when
    one comes from the data, with no bound, or with a zero step (refused when it runs)."""
    numbers = [None if value is None else _const_number(value) for value in given]
    if any(
        value is not None and number is None for value, number in zip(given, numbers, strict=True)
    ):
        return None
    start, stop, step = numbers
    if start is None and stop is None:
        return None
    low, high = (0, start) if stop is None else (start or 0, stop)
    step = 1 if step is None else step
    if step == 0:
        return None
    try:
        span = abs(high - low)
    except OverflowError:  # a float bound beside an integer past any float: that integer's size
        return max(abs(bound) for bound in (low, high) if isinstance(bound, int))
    if isinstance(span, int) and isinstance(step, int):
        return -(-span // abs(step))
    try:
        return math.ceil(span / abs(step))
    except OverflowError:  # 1.0 / 1e-320 is inf: numpy refuses a size past its maximum itself
        return None


class _Checker(ast.NodeVisitor):
    def __init__(self, local_names: set[str]) -> None:
        self.local_names = local_names
        self._module_bases: set[int] = set()  # every Name node that heads an attribute

    def generic_visit(self, node: ast.AST) -> None:
        if not isinstance(node, _ALLOWED_NODES):
            why = _NODE_WHY.get(type(node), f"{type(node).__name__} is not allowed")
            raise _violation(node, why)
        super().generic_visit(node)

    def visit_Import(self, node: ast.Import) -> None:
        for alias in node.names:
            if (alias.name, alias.asname) not in (
                ("numpy", "np"),
                ("math", None),
                ("math", "math"),
            ):
                raise _violation(
                    node, f"import {alias.name!r} is not allowed (only 'import numpy as np' and "
                    "'import math')"
                )  # fmt: skip

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        if node.module != "math" or node.level:
            raise _violation(node, f"from {node.module} import ... is not allowed (only from math)")
        for alias in node.names:
            if alias.name not in MATH_ALLOWED:
                raise _violation(node, f"math.{alias.name} is not allowed")
            self._check_binding(node, alias.asname or alias.name)

    def visit_FunctionDef(self, node: ast.FunctionDef) -> None:
        if node.decorator_list:
            raise _violation(node, "decorators are not allowed")
        if node.returns is not None:
            node.returns = None  # annotations are never evaluated by the sandbox
        self._check_binding(node, node.name)
        for arg in node.args.posonlyargs + node.args.args + node.args.kwonlyargs:
            self._check_binding(arg, arg.arg)
            arg.annotation = None
        for arg in (node.args.vararg, node.args.kwarg):
            if arg is not None:
                self._check_binding(arg, arg.arg)
                arg.annotation = None
        self.generic_visit(node)

    def _check_name(self, node: ast.AST, name: str) -> None:
        if name.startswith("_"):
            raise _violation(node, f"names starting with '_' are not allowed ({name!r})")

    def _check_binding(self, node: ast.AST, name: str) -> None:
        """A name the code binds (a function, an argument, an import alias): ``np`` and
        ``math`` only by their imports, since ``np.X`` is checked against numpy's allowlist
        whatever ``np`` holds (a parameter named ``np`` would open every method of an array)."""
        self._check_name(node, name)
        if name in ("np", "math"):
            raise _violation(node, f"{name!r} may only be bound by its import")

    def visit_Name(self, node: ast.Name) -> None:
        self._check_name(node, node.id)
        if isinstance(node.ctx, ast.Store) and node.id in ("np", "math"):
            raise _violation(node, f"assigning to {node.id!r} is not allowed")
        if (
            isinstance(node.ctx, ast.Load)
            and node.id not in self.local_names
            and node.id not in SAFE_BUILTINS
            and node.id not in ("np", "math")
        ):
            raise _violation(node, f"name {node.id!r} is not allowed (not a safe builtin)")
        if node.id in ("np", "math") and id(node) not in self._module_bases:
            # The allowlists are checked on np.NAME and math.NAME: an alias (n = np) would
            # reach any numpy function through a method name.
            raise _violation(node, f"{node.id!r} may only be used as {node.id}.NAME")

    def visit_Attribute(self, node: ast.Attribute) -> None:
        if isinstance(node.value, ast.Name):
            self._module_bases.add(id(node.value))
        if not isinstance(node.ctx, ast.Load):
            # np.linalg.norm = ... would change numpy for the whole process: the host's own
            # success checks included.
            raise _violation(node, "assigning to or deleting an attribute is not allowed")
        self.generic_visit(node)  # inner first: np.lib.format.open_memmap is refused at np.lib
        attr = node.attr
        if attr.startswith("_"):
            raise _violation(node, f"attribute {attr!r} is not allowed (starts with '_')")
        base = node.value
        if _is_module(base, "np"):
            if attr not in NUMPY_ALLOWED:
                raise _violation(node, f"np.{attr} is not allowed")
        elif (
            isinstance(base, ast.Attribute)
            and _is_module(base.value, "np")
            and base.attr == "linalg"
        ):
            if attr not in LINALG_ALLOWED:
                raise _violation(node, f"np.linalg.{attr} is not allowed")
        elif _is_module(base, "math"):
            if attr not in MATH_ALLOWED:
                raise _violation(node, f"math.{attr} is not allowed")
        elif attr not in METHOD_ALLOWED:
            raise _violation(node, f"attribute .{attr} is not allowed")

    def visit_BinOp(self, node: ast.BinOp) -> None:
        _const_int(node)  # refuses huge constant powers
        if (
            isinstance(node.op, ast.Mod)
            and isinstance(node.left, ast.Constant)
            and isinstance(node.left.value, (str, bytes))
        ):
            template = node.left.value
            if isinstance(template, bytes):
                template = template.decode("latin-1")
            if _UNREAD_PERCENT.search(template):
                # A width taken from the arguments, or a mapping key this check cannot read.
                raise _violation(node, "a * width or a mapping key with parentheses in a % "
                                 "template is not allowed")  # fmt: skip
            # Each conversion's width and precision, as digits (empty where not given).
            _check_format_widths(
                node, *(n for spec in _PERCENT_SPEC.findall(template) for n in spec)
            )
        if isinstance(node.op, ast.Mult):
            size = _elements(node)
            if size is not None and size > MAX_CONSTANT_ELEMENTS:
                raise _violation(node, f"sequence repeated to {_shown(size)} elements is too large")
        self.generic_visit(node)

    def visit_Call(self, node: ast.Call) -> None:
        func = node.func
        if (
            isinstance(func, ast.Attribute)
            and _is_module(func.value, "np")
            and func.attr in _SIZE_CHECKED
            and (
                any(isinstance(a, ast.Starred) for a in node.args)
                or any(k.arg is None for k in node.keywords)
            )
        ):
            # A size unpacked from * or ** cannot be read before the code runs.
            raise _violation(node, f"np.{func.attr} takes its size as written, not through * or **")
        if isinstance(func, ast.Name) and func.id == "range" and len(node.args) <= 3:
            size = _arange_length(*node.args, *[None] * (3 - len(node.args)))
        else:
            size = _elements(node)
        if size is not None and size > MAX_CONSTANT_ELEMENTS:
            raise _violation(node, f"constant size {_shown(size)} is too large")
        dtypes = [k.value for k in node.keywords if k.arg == "dtype"]
        if isinstance(func, ast.Attribute):
            # Where numpy takes the dtype by position; a text fill value makes a text array.
            at = 0 if func.attr == "astype" else _DTYPE_POSITION.get(func.attr)
            if at is not None and (func.attr == "astype" or _is_module(func.value, "np")):
                dtypes += node.args[at : at + 1]
        for dtype in dtypes:
            if _names_flexible_dtype(dtype):
                raise _violation(node, _TEXT_ARRAYS)
        if (
            isinstance(func, ast.Attribute)
            and _is_module(func.value, "np")
            and func.attr in ("full", "full_like")
            and any(
                _is_text(a)
                for a in [
                    *node.args[1:2],
                    *(k.value for k in node.keywords if k.arg == "fill_value"),
                ]
            )
        ):
            raise _violation(node, _TEXT_ARRAYS)
        self.generic_visit(node)

    def visit_FormattedValue(self, node: ast.FormattedValue) -> None:
        spec = node.format_spec
        if isinstance(spec, ast.JoinedStr):
            for part in spec.values:
                if isinstance(part, ast.Constant) and isinstance(part.value, str):
                    _check_format_widths(node, part.value)
                else:
                    # f"{x:{10**8}}": a width no check here can read (one from the data no
                    # less), and no reward needs one.
                    raise _violation(
                        node, "a format spec computed inside the f-string; write it as a number"
                    )
        self.generic_visit(node)


def _names_flexible_dtype(node: ast.AST) -> bool:
    """Whether ``node`` names a string, bytes, void or object dtype as written: a string
    (``"U1000"``, ``"S"``) or the type (``str``, ``np.bytes_``). A dtype computed from the data
    is left to the process limits."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return bool(_FLEXIBLE_DTYPES.match(node.value.strip()))
    if isinstance(node, ast.Name):
        # The builtins only: a variable of the reward's own (``acc = np.float64``) says nothing.
        return node.id in ("str", "bytes", "object")
    if isinstance(node, ast.Attribute) and _is_module(node.value, "np"):
        return bool(_FLEXIBLE_DTYPES.match(node.attr))
    return False


def _is_text(node: ast.AST) -> bool:
    """Whether ``node`` is a string or bytes as written: a literal, an f-string, or one repeated,
    joined or %-formatted (``"x" * 1000``)."""
    if isinstance(node, ast.Constant):
        return isinstance(node.value, (str, bytes))
    if isinstance(node, ast.JoinedStr):
        return True
    return isinstance(node, ast.BinOp) and (_is_text(node.left) or _is_text(node.right))


def _check_format_widths(node: ast.AST, *specs: str) -> None:
    """Refuse format specs (an f-string's, those of a ``%`` template; ``str.format`` is not
    allowed) that ask for a width or precision above :data:`MAX_FORMAT_WIDTH`."""
    for number in (n for spec in specs for n in _FORMAT_NUMBER.findall(spec)):
        if len(number) > 12 or int(number) > MAX_FORMAT_WIDTH:
            raise _violation(
                node, f"format width {number} is too large (at most {MAX_FORMAT_WIDTH:,})"
            )


def _is_module(node: ast.AST, name: str) -> bool:
    """Whether ``node`` is the name ``name`` (``np`` or ``math``: only their imports bind them)."""
    return isinstance(node, ast.Name) and node.id == name


def _bound_names(tree: ast.AST) -> set[str]:
    """Every name the code binds itself: assignments, loop targets, functions, arguments,
    imports."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.FunctionDef):
            names.add(node.name)
        elif isinstance(node, ast.arg):
            names.add(node.arg)
        elif isinstance(node, ast.alias):
            names.add(node.asname or node.name.split(".")[0])
    return names


def check_source(source: str, config: SandboxConfig | None = None) -> ast.Module:
    """Parse ``source`` and check it against the allowlists; :class:`SandboxViolation` if not."""
    config = config or SandboxConfig()
    if not isinstance(source, str) or not source.strip():
        raise SandboxViolation("the code is empty")
    if len(source) > config.max_source_chars:
        raise SandboxViolation(
            f"the code is {len(source)} characters long; the limit is {config.max_source_chars}"
        )
    try:
        tree = ast.parse(source, filename=FILENAME)
    except SyntaxError as err:
        raise SandboxViolation(f"line {err.lineno}: syntax error: {err.msg}") from err
    except (ValueError, RecursionError, MemoryError) as err:
        raise SandboxViolation(f"the code cannot be parsed: {err}") from err
    try:
        _Checker(_bound_names(tree)).visit(tree)
    except RecursionError as err:
        raise SandboxViolation("the code is nested too deeply") from err
    return tree


# ------------------------------------------------------------------------------ execution
def _importer(name: str, globals=None, locals=None, fromlist=(), level=0):
    """The ``__import__`` of the sandbox: numpy and math only (the checker already refused the
    rest; this is the second lock).

    NumPy's C code imports some of its own modules on first use (``arr.sum(axis=1)`` imports
    ``numpy._core._methods``) through the ``__import__`` of the frame that calls it, this one:
    those are served, or a valid reward failed in a process where nothing had summed an array
    yet. The code itself cannot ask for them: the checker allows ``import numpy`` and
    ``import math`` only, and no name starting with ``_``."""
    if level == 0 and name == "numpy":
        return np
    if level == 0 and name == "math":
        return math
    if level == 0 and name.startswith("numpy.") and type(fromlist) is list:
        # Only as NumPy's C code asks (a list; an import statement passes None or a tuple): a
        # lock should hold even if the checker before it were ever wrong.
        return builtins.__import__(name, globals, locals, fromlist, level)
    raise ImportError(f"import of {name!r} is not allowed in the sandbox")


def _namespace() -> dict[str, Any]:
    safe = {name: getattr(builtins, name) for name in SAFE_BUILTINS}
    safe["__import__"] = _importer
    return {"__builtins__": safe, "__name__": "reward", "np": np, "math": math}


@contextmanager
def _deadline(seconds: float | None) -> Iterator[None]:
    """Raise :class:`SandboxTimeout` in the calling thread after ``seconds``.

    In the main thread a ``SIGALRM`` interval timer does it; elsewhere (signals only reach the
    main thread) a watchdog thread injects the exception with ``PyThreadState_SetAsyncExc``.
    Either way the exception arrives between bytecodes: one long NumPy call finishes first.
    """
    if not seconds or seconds <= 0:
        yield
        return
    if threading.current_thread() is threading.main_thread() and hasattr(signal, "setitimer"):

        def on_alarm(signum, frame):
            raise SandboxTimeout(f"the reward code ran longer than {seconds:g} s")

        previous = signal.signal(signal.SIGALRM, on_alarm)
        signal.setitimer(signal.ITIMER_REAL, seconds)
        try:
            yield
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
        return
    target = threading.get_ident()
    done = threading.Event()

    def watchdog() -> None:
        if not done.wait(seconds):
            ctypes.pythonapi.PyThreadState_SetAsyncExc(
                ctypes.c_ulong(target), ctypes.py_object(SandboxTimeout)
            )

    thread = threading.Thread(target=watchdog, daemon=True)
    thread.start()
    try:
        yield
    except SandboxTimeout as err:
        raise SandboxTimeout(f"the reward code ran longer than {seconds:g} s") from err
    finally:
        done.set()
        thread.join()


MESSAGE_MAX = 2000
"""The most characters of an exception's message kept in a failure: the failure is fed back to
the model, and a reward raising a ten-million-character message made a prompt the endpoint
refused, which ended the whole search."""


def _traceback_tail(err: BaseException, source: str, lines: int = 6) -> str:
    """The reward's own frames of ``err`` (line number and the line of ``source``, which the
    code is compiled from and no file holds) and its message, cut to :data:`MESSAGE_MAX`."""
    code_lines = re.split(r"\r\n|\r|\n", source)  # as Python numbers lines (not at a form feed)
    frames = [
        f"line {frame.lineno}: {code_lines[frame.lineno - 1].strip()}"
        if frame.lineno and 0 < frame.lineno <= len(code_lines)
        else f"line {frame.lineno}"
        for frame in traceback.extract_tb(err.__traceback__)
        if frame.filename == FILENAME
    ]
    message = "".join(traceback.format_exception_only(type(err), err)).strip()
    return "\n".join([*frames[-lines:], _cut(message)])


def _cut(message: str) -> str:
    """``message`` to at most :data:`MESSAGE_MAX` characters, saying how many were cut."""
    if len(message) <= MESSAGE_MAX:
        return message
    return f"{message[:MESSAGE_MAX]} ... ({len(message) - MESSAGE_MAX:,} characters cut)"


def _run(fn, *args: Any, source: str, timeout: float | None) -> Any:
    """``fn(*args)`` under the time limit; a failure as a :class:`SandboxError` that says why,
    with the frames of ``source`` it passed through."""
    try:
        with _deadline(timeout):
            return fn(*args)
    except SandboxTimeout:
        raise
    except RewardOutputError as err:
        raise SandboxError(_cut(str(err))) from err
    except MemoryError as err:
        # Its message is often empty: the line it failed on is what tells the model what to fix.
        tail = _traceback_tail(err, source)
        raise SandboxError(f"the reward code ran out of memory:\n{tail}") from err
    except RecursionError as err:
        tail = _traceback_tail(err, source)
        raise SandboxError(f"the reward code recursed too deeply:\n{tail}") from err
    except Exception as err:
        raise SandboxError(f"the reward code raised:\n{_traceback_tail(err, source)}") from err


def _read_only(ctx: Mapping[str, Any]) -> dict[str, Any]:
    """A copy of the context whose arrays are read-only views: the code cannot write into the
    simulator's state."""
    out = {}
    for key, value in ctx.items():
        if isinstance(value, np.ndarray):
            value = value.view()
            value.flags.writeable = False
        out[key] = value
    return out


class SandboxedReward:
    """A checked reward function: ``reward(ctx) -> (total[N], {name: [N]})``, all float64, finite.

    Every call runs under the time limit with a read-only context; a failure is a
    :class:`SandboxError` (or :class:`SandboxTimeout`) with the reason.
    """

    def __init__(self, fn: Any, source: str, config: SandboxConfig) -> None:
        self._fn = fn
        self.source = source
        self.sha256 = hashlib.sha256(source.encode()).hexdigest()
        self.config = config

    def __call__(self, ctx: Mapping[str, Any]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        n = int(np.asarray(ctx["ee_pos"]).shape[0])

        def checked(view: dict[str, Any]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
            # Under the same time limit as the code: converting what it returns runs its work
            # too (a list that holds itself took NumPy's conversion past any limit).
            return check_reward_output(self._fn(view), n)

        return _run(
            checked, _read_only(ctx), source=self.source, timeout=self.config.call_timeout_s
        )

    def __getstate__(self) -> dict[str, Any]:
        # The function cannot be pickled; the source can, and is re-checked on arrival.
        return {"source": self.source, "config": self.config}

    def __setstate__(self, state: dict[str, Any]) -> None:
        other = compile_reward(state["source"], state["config"])
        self.__dict__.update(other.__dict__)


def compile_reward(source: str, config: SandboxConfig | None = None) -> SandboxedReward:
    """Check ``source``, run its module body in the sandbox and return its ``compute_reward``."""
    config = config or SandboxConfig()
    tree = check_source(source, config)
    try:
        code = compile(tree, FILENAME, "exec")
    except SyntaxError as err:  # what parses may still not compile: `continue` outside a loop
        raise SandboxViolation(f"line {err.lineno}: syntax error: {err.msg}") from err
    except (ValueError, RecursionError, MemoryError) as err:
        raise SandboxViolation(f"the code cannot be compiled: {err}") from err
    namespace = _namespace()
    _run(exec, code, namespace, source=source, timeout=config.call_timeout_s)
    fn = namespace.get("compute_reward")
    if not callable(fn) or not hasattr(fn, "__code__"):
        raise SandboxError("the code defines no function compute_reward(ctx)")
    if fn.__code__.co_argcount < 1:
        raise SandboxError("compute_reward must take the context as its argument")
    return SandboxedReward(fn, source, config)


def apply_process_limits(config: SandboxConfig) -> None:
    """Cap this process's CPU time (``RLIMIT_CPU``, SIGXCPU when exceeded) and address space
    (``RLIMIT_AS``, allocations fail with MemoryError beyond it).

    Call it at the start of a worker process that runs generated code, never in the main CLI
    process: the limits hold for the rest of the process's life. Limits only ever go down.
    """
    import resource

    def lower(kind: int, value: int) -> None:
        soft, hard = resource.getrlimit(kind)
        if hard != resource.RLIM_INFINITY:
            value = min(value, hard)
        if soft != resource.RLIM_INFINITY:
            value = min(value, soft)
        resource.setrlimit(kind, (value, hard))

    if config.cpu_limit_s is not None:
        lower(resource.RLIMIT_CPU, int(config.cpu_limit_s))
    if config.memory_limit_mb is not None:
        _cap_malloc_arenas()
        lower(resource.RLIMIT_AS, int(config.memory_limit_mb) * 1024 * 1024)


MALLOC_ARENAS = 2
_M_ARENA_MAX = -8  # glibc's mallopt parameter


def _cap_malloc_arenas() -> None:
    """Let glibc's malloc keep :data:`MALLOC_ARENAS` arenas, not one per thread up to 8 per core.

    Each arena reserves 64 MB of address space, so under ``RLIMIT_AS`` the simulation's worker
    threads rather than the memory in use decided when allocations failed: 16 threads took
    2.6 GB of a 4 GB limit before training began, 1.8 GB with two arenas. Where the C library is
    not glibc (no ``mallopt``) there is no such reservation to cap.
    """
    mallopt = getattr(ctypes.CDLL(None), "mallopt", None)
    if mallopt is not None:
        mallopt(_M_ARENA_MAX, MALLOC_ARENAS)


def death_cause(exitcode: int | None, config: SandboxConfig, process: str) -> str:
    """Why ``process`` (a worker under :func:`apply_process_limits`) ended with ``exitcode``."""
    if exitcode is not None and exitcode < 0:
        try:
            sig = signal.Signals(-exitcode)
        except ValueError:  # a real-time signal has no name
            return f"{process} was killed by signal {-exitcode}"
        if sig == signal.SIGXCPU:
            return f"CPU time limit of {config.cpu_limit_s} s exceeded (killed by SIGXCPU)"
        if sig == signal.SIGKILL:
            return "killed by SIGKILL (out of memory?)"
        return f"{process} was killed by {sig.name}"
    return f"{process} exited with code {exitcode} without a result"
