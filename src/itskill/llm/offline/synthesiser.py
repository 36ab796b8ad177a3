"""The offline reward synthesiser: staged reward code composed by rule from a task description.

It reads the stage lines of the generator prompt's task description (``stage K: NAME | object I |
done when EXPR``), picks the shaping terms of each stage from its action (``terms.toml``:
``[recipes]`` and ``[terms]``), and writes a ``compute_reward(ctx)`` in the same shape a language
model must use: one temperature variable per transformed term, one weight per term, a stage bonus,
a success bonus and an action penalty, components named ``"<k>.<stage>/<term>"``.

Sample 0 of a request uses the defaults (or, with policy feedback, the retuned values); samples
1.. vary temperatures, weights and the transform, seeded by the sample index and the prompt, so
replies are deterministic. Policy feedback is handled by rule (see ``[retune]`` in the data file):
a term that never gets near its maximum gets a wider temperature, one always near it a narrower
one, the first stage never reached more weight and the stage before it wider temperatures.
"""

from __future__ import annotations

import hashlib
import inspect
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from itskill.datafile import (
    DataFileError,
    check_format_text,
    check_nonnegative,
    check_table,
    read_toml,
)
from itskill.llm.offline.backend import BACKEND
from itskill.llm.offline.blocks import fenced
from itskill.tasks.predicates import PREDICATES, PredicateError, parse, predicate_params

_STAGE = re.compile(
    r"^\s*stage\s+(\d+)\s*:\s*([A-Za-z_][\w\-]*)\s*\|\s*object\s+(\d+)\s*\|"
    r"\s*done when\s+(.+?)\s*$",
    re.M | re.I,
)
_OBJECT = re.compile(r"^\s*object\s+(\d+)\s*:.*?for fixture\s+(\d+)", re.M | re.I)
_SUCCESS = re.compile(r"^\s*Success:\s*(.+?)\s*$", re.M)
_COMMAND = re.compile(r"^\s*Command:\s*(.+?)\s*$", re.M)
_ASSIGN = re.compile(r"^\s*((?:temp|w)_\w+|stage_bonus|success_bonus|action_penalty)\s*=\s*"
                     r"([-+0-9.eE]+)\s*(?:#.*)?$", re.M)  # fmt: skip
_STAT = re.compile(r"^\s*([^|\n]+?)\s*\|\s*([-+0-9.eE]+|nan|inf)\s*\|\s*([-+0-9.eE]+|nan|inf)\s*\|"
                   r"\s*([-+0-9.eE]+|nan|inf)\s*$", re.M)  # fmt: skip
_COMPONENT = re.compile(r"^(\d+)\.[^/]+/(\w+)$")
_SUCCESS_RATE = re.compile(r"success rate:\s*([0-9.]+)", re.I)

# Which recipe a stage gets when its action is not a recipe name: by its condition.
_RECIPE_OF_PREDICATE = {
    "near": "approach",
    "over_fixture": "hover",
    "grasped": "grasp",
    "lifted": "lift",
    "above_fixture": "carry",
    "aligned": "align",
    "engaged": "place",
    "seated": "screw",
    "inserted": "insert",
    "removed": "unscrew",
    "displaced": "push",
    "released": "release",
}
_ACTION_ALIASES = {"reach": "approach", "move": "approach", "transport": "carry", "pull": "remove"}


class SynthesisError(ValueError):
    """The prompt has no task description the synthesiser can read."""


class VocabularyError(DataFileError):
    """A ``terms.toml`` that does not validate: names the file, the field and the problem."""


STAGE_FIELDS: dict[str, Any] = {
    "target": '3.0 * ctx["obj_height"][:, 0]',
    "hover": 0.015,
    "hover_height": 0.05,
    "tolerance": 0.0,
    "fraction": 0.5,
    "height": 0.02,
    "dx": 0.0,
    "dy": 0.0,
    "degrees": 20.0,
}
"""The fields a term's text may use besides ``{i}`` and ``{j}``, with their defaults (the
``target`` one for slot 0): what :func:`_fields` fills from a stage's condition."""

_SECTIONS = ("recipes", "conditions", "terms", "predicates", "defaults", "variation", "retune")
_TERM_KEYS = {
    "distance": ("doc", "kind", "weight", "distance", "temperature"),
    "flag": ("doc", "kind", "weight", "value"),
}
_TERM_OPTIONAL = ("gate", "floor")
_DEFAULT_KEYS = ("transform", "stage_bonus", "success_bonus", "action_penalty")
_TRANSFORMS = ("exp", "tanh")
_RETUNE_FACTORS = (
    "dead_max",
    "saturated_min",
    "widen",
    "narrow",
    "unreached_weight",
    "bottleneck_widen",
    "success_bonus_factor",
)


def terms_path() -> Path:
    """The packaged ``terms.toml``, the synthesiser's vocabulary."""
    return Path(str(resources.files("itskill.llm.offline") / "terms.toml"))


def _required_recipes() -> set[str]:
    """Every recipe :func:`_recipe` can choose, whatever the task: each must be in the file."""
    return {"approach", "hover", "carry", "remove", *_RECIPE_OF_PREDICATE.values()}


def _exact_keys(path: Path, where: str, table: dict[str, Any], keys: Sequence[str]) -> None:
    """Every one of ``keys`` in ``table`` and nothing else: an unknown key (a misspelt one) would
    be ignored, a missing one a ``KeyError`` once a reward is written."""
    check_table(path, where, table, VocabularyError, keys)
    for key in keys:
        if key not in table:
            raise VocabularyError(path, f"{where}.{key}", "missing")


def _number_range(path: Path, where: str, value: Any, positive: bool = False) -> None:
    """``value`` as ``[low, high]``, numbers as :func:`check_nonnegative` takes, ``low <= high``."""
    if not isinstance(value, list) or len(value) != 2:
        raise VocabularyError(path, where, f"expected [low, high], got {value!r}")
    low, high = (
        check_nonnegative(path, f"{where}[{k}]", v, VocabularyError, positive)
        for k, v in enumerate(value)
    )
    if low > high:
        raise VocabularyError(path, where, f"low {low} is above high {high}")


def _check_names(
    path: Path, where: str, value: Any, terms: dict[str, Any], empty: bool = False
) -> None:
    """``value`` as a list of term names defined in ``[terms]``, each once."""
    if not isinstance(value, list) or (not value and not empty):
        raise VocabularyError(path, where, f"expected a list of term names, got {value!r}")
    for name in value:
        if name not in terms:
            known = ", ".join(sorted(terms))
            raise VocabularyError(path, where, f"unknown term {name!r}; known: {known}")
    if len(set(value)) != len(value):
        raise VocabularyError(path, where, f"a term is listed twice in {value}")


def _check_term(path: Path, name: str, term: Any) -> None:
    where = f"terms.{name}"
    term = check_table(path, where, term, VocabularyError)
    kind = term.get("kind")
    if kind not in _TERM_KEYS:
        needed = ", ".join(dict.fromkeys(k for keys in _TERM_KEYS.values() for k in keys))
        raise VocabularyError(
            path, where, f"needs kind 'distance' or 'flag' and {needed}; got kind {kind!r}"
        )
    needed = _TERM_KEYS[kind]
    missing = [key for key in needed if key not in term]
    if missing:
        raise VocabularyError(
            path,
            where,
            f"needs kind 'distance' or 'flag' and {', '.join(needed)}; missing {missing[0]}",
        )
    for key in term:
        if key not in needed and key not in _TERM_OPTIONAL:
            # A 'value' on a distance term (or the reverse) would be silently left unused.
            raise VocabularyError(
                path,
                f"{where}.{key}",
                f"not used by a {kind!r} term; it takes {', '.join(needed + _TERM_OPTIONAL)}",
            )
    check_nonnegative(path, f"{where}.weight", term["weight"], VocabularyError)
    if kind == "distance":
        # The temperature divides the distance: 0 would make every value NaN.
        check_nonnegative(
            path, f"{where}.temperature", term["temperature"], VocabularyError, positive=True
        )
    sample = {"i": 0, "j": 0, **STAGE_FIELDS}
    for key in ("doc", "distance", "value", *_TERM_OPTIONAL):
        if key in term:
            check_format_text(path, f"{where}.{key}", term[key], sample, VocabularyError)


def check_vocabulary(data: dict[str, Any], path: Path) -> dict[str, Any]:
    """``data`` (a parsed ``terms.toml``) if every entry is usable; :class:`VocabularyError`
    names the first that is not."""
    check_table(path, "", data, VocabularyError, _SECTIONS, "table")
    for section in _SECTIONS:
        if section not in data:
            raise VocabularyError(path, section, f"missing [{section}] table")
        check_table(path, section, data[section], VocabularyError)
    terms = data["terms"]
    for name, term in terms.items():
        _check_term(path, name, term)
    for key, names in data["recipes"].items():
        _check_names(path, f"recipes.{key}", names, terms)
    missing = sorted(_required_recipes() - set(data["recipes"]))
    if missing:
        raise VocabularyError(
            path, f"recipes.{missing[0]}", "missing: the synthesiser picks this recipe by rule"
        )
    for key, names in data["conditions"].items():
        if key not in PREDICATES:
            raise VocabularyError(
                path,
                f"conditions.{key}",
                f"unknown predicate; known: {', '.join(sorted(PREDICATES))}",
            )
        _check_names(path, f"conditions.{key}", names, terms, empty=True)
    if set(data["predicates"]) != set(PREDICATES):
        raise VocabularyError(path, "predicates", f"must cover exactly {sorted(PREDICATES)}")
    for name, code in data["predicates"].items():
        params = list(inspect.signature(PREDICATES[name]).parameters)[1:]  # drop ctx
        sample = dict.fromkeys(["i", "j", *params], 0)
        check_format_text(path, f"predicates.{name}", code, sample, VocabularyError)
    defaults = data["defaults"]
    _exact_keys(path, "defaults", defaults, _DEFAULT_KEYS)
    if defaults["transform"] not in _TRANSFORMS:
        raise VocabularyError(
            path,
            "defaults.transform",
            f"expected one of {', '.join(_TRANSFORMS)}, got {defaults['transform']!r}",
        )
    for key in _DEFAULT_KEYS[1:]:
        check_nonnegative(path, f"defaults.{key}", defaults[key], VocabularyError)
    variation = data["variation"]
    _exact_keys(
        path, "variation", variation, ("temperature_factor", "weight_factor", "tanh_probability")
    )
    # Temperature factors are drawn log-uniformly: 0 has no logarithm.
    _number_range(path, "variation.temperature_factor", variation["temperature_factor"], True)
    _number_range(path, "variation.weight_factor", variation["weight_factor"])
    if (
        check_nonnegative(
            path, "variation.tanh_probability", variation["tanh_probability"], VocabularyError
        )
        > 1
    ):
        raise VocabularyError(
            path,
            "variation.tanh_probability",
            f"expected a probability in [0, 1], got {variation['tanh_probability']!r}",
        )
    retune = data["retune"]
    _exact_keys(path, "retune", retune, (*_RETUNE_FACTORS, "temperature_range", "weight_range"))
    for key in _RETUNE_FACTORS:
        check_nonnegative(path, f"retune.{key}", retune[key], VocabularyError)
    # Temperatures are clamped into this range and divide distances: its low end must be > 0.
    _number_range(path, "retune.temperature_range", retune["temperature_range"], True)
    _number_range(path, "retune.weight_range", retune["weight_range"])
    return data


@cache
def vocabulary(path: Path | None = None) -> dict[str, Any]:
    """The synthesiser's data file (default :func:`terms_path`), every entry checked: the
    tables it needs, every recipe term defined, every term complete with placeholders it can
    fill, numbers finite and >= 0 (:class:`VocabularyError`)."""
    source = path or terms_path()
    return check_vocabulary(read_toml(source, VocabularyError), source)


# ------------------------------------------------------------------------------ task structure
@dataclass(frozen=True)
class StageSpec:
    """One stage as read from the description: its recipe, its shaping terms (the recipe's and
    those its done condition calls for) and the fields the terms need."""

    index: int
    action: str
    recipe: str
    slot: int
    fields: dict[str, Any]
    terms: tuple[str, ...]


@dataclass(frozen=True)
class TaskStructure:
    command: str
    stages: tuple[StageSpec, ...]
    success: str  # NumPy expression


def _expression_code(source: str, fixture_of: dict[int, int]) -> str:
    """NumPy code for a predicate expression such as ``lifted(0, 3) and grasped(0)``."""
    parts = []
    for negate, name, args in parse(source).terms:
        params = predicate_params(name, args)
        slot = int(params["i"])
        code = vocabulary()["predicates"][name].format(
            **{**params, "i": slot, "j": fixture_of.get(slot, slot)}
        )
        parts.append(f"~({code})" if negate else f"({code})")
    return " & ".join(parts)


def parse_description(text: str) -> TaskStructure:
    """Stages, objects' fixtures and the success condition from a task description."""
    fixture_of = {int(i): int(j) for i, j in _OBJECT.findall(text)}
    rows = _STAGE.findall(text)
    if not rows:
        raise SynthesisError(
            "the task description has no stage lines ('stage K: NAME | object I | done when EXPR')"
        )
    stages: list[StageSpec] = []
    held: set[int] = set()  # object slots in the hand, as far as the stage sequence tells
    for k, (index, action, slot_text, done) in enumerate(rows):
        if int(index) != k:
            raise SynthesisError(f"stage lines must be numbered 0, 1, ... in order; got {index}")
        slot = int(slot_text)
        try:
            terms = parse(done).terms
        except PredicateError:
            terms = ()
        names = [name for neg, name, _ in terms if not neg]
        recipe = _recipe(action.lower(), names, slot in held)
        stages.append(
            StageSpec(
                k, action, recipe, slot, _fields(slot, fixture_of, terms), _terms(recipe, names)
            )
        )
        if recipe in ("grasp", "lift", "unscrew", "remove"):
            held.add(slot)
        elif recipe in ("place", "insert", "release", "push"):
            held.discard(slot)
    match = _SUCCESS.search(text)
    try:
        success = _expression_code(match.group(1), fixture_of) if match else ""
    except PredicateError as err:
        raise SynthesisError(f"cannot read the success condition: {err}") from err
    if not success:  # no usable success line: the last stage being done is the goal
        success = _expression_code(rows[-1][3], fixture_of)
    command = _COMMAND.search(text)
    return TaskStructure(command.group(1) if command else "", tuple(stages), success)


def _recipe(action: str, predicates: list[str], holding: bool) -> str:
    recipes = vocabulary()["recipes"]
    action = _ACTION_ALIASES.get(action, action)
    if action == "approach" and "over_fixture" in predicates:
        return "hover"
    if action == "approach" and ("above_fixture" in predicates or holding):
        return "carry"
    if action == "lift" and "removed" in predicates:
        return "remove"
    if action in recipes:
        return action
    for name in predicates:
        if name in _RECIPE_OF_PREDICATE:
            return _RECIPE_OF_PREDICATE[name]
    return "approach"


def _terms(recipe: str, predicates: list[str]) -> tuple[str, ...]:
    """The recipe's terms, then those the done condition's predicates add (once each)."""
    vocab = vocabulary()
    names = list(vocab["recipes"][recipe])
    for predicate in predicates:
        names += [t for t in vocab["conditions"].get(predicate, ()) if t not in names]
    return tuple(names)


def _fields(slot: int, fixture_of: dict[int, int], terms) -> dict[str, Any]:
    j = fixture_of.get(slot, slot)
    # The defaults are those terms.toml is checked against, so that every field it may use is set.
    fields: dict[str, Any] = {
        "i": slot,
        "j": j,
        **STAGE_FIELDS,
        "target": f'3.0 * ctx["obj_height"][:, {slot}]',
    }
    for negate, name, args in terms:
        if negate or int(args[0]) != slot:
            continue
        p = predicate_params(name, args)
        if name == "lifted":
            fields["target"] = f'{float(p["heights"])!r} * ctx["obj_height"][:, {slot}]'
        elif name == "above_fixture":
            fields["hover"] = 0.5 * float(p["height"])
        elif name == "over_fixture":
            fields["hover_height"] = float(p["height"])
        elif name == "seated":
            fields["tolerance"] = float(p["tolerance"])
        elif name == "inserted":
            fields["fraction"] = float(p["fraction"])
        elif name == "removed":
            fields["height"] = float(p["height"])
        elif name == "upright":
            fields["degrees"] = float(p["degrees"])
        elif name == "displaced":
            fields["dx"], fields["dy"] = float(p["dx"]), float(p["dy"])
    return fields


# ------------------------------------------------------------------------------ parameters
@dataclass
class RewardParams:
    """Every number in a generated reward: temperatures and weights by variable name."""

    temperatures: dict[str, float] = field(default_factory=dict)
    weights: dict[str, float] = field(default_factory=dict)
    transform: str = "exp"
    stage_bonus: float = 1.0
    success_bonus: float = 2.0
    action_penalty: float = 0.01

    def copy(self) -> RewardParams:
        return replace(self, temperatures=dict(self.temperatures), weights=dict(self.weights))


def default_params(task: TaskStructure) -> RewardParams:
    vocab = vocabulary()
    params = RewardParams(
        transform=vocab["defaults"]["transform"],
        stage_bonus=float(vocab["defaults"]["stage_bonus"]),
        success_bonus=float(vocab["defaults"]["success_bonus"]),
        action_penalty=float(vocab["defaults"]["action_penalty"]),
    )
    for stage in task.stages:
        for name in stage.terms:
            term = vocab["terms"][name]
            params.weights[f"w_{name}_{stage.index}"] = float(term["weight"])
            if term["kind"] == "distance":
                params.temperatures[f"temp_{name}_{stage.index}"] = float(term["temperature"])
    return params


def vary(params: RewardParams, seed: int) -> RewardParams:
    """A deterministic variation of ``params`` for one sample."""
    cfg = vocabulary()["variation"]
    rng = np.random.default_rng(seed)
    out = params.copy()
    lo, hi = (math.log(v) for v in cfg["temperature_factor"])
    for key in out.temperatures:
        out.temperatures[key] *= math.exp(rng.uniform(lo, hi))
    for key in out.weights:
        out.weights[key] *= rng.uniform(*cfg["weight_factor"])
    out.transform = "tanh" if rng.random() < cfg["tanh_probability"] else "exp"
    return out


def retune(
    task: TaskStructure,
    previous_code: str,
    success_rate: float | None,
    stats: dict[str, dict[str, float]],
) -> tuple[RewardParams, list[str]]:
    """New parameters from the previous code's values and the training statistics, with notes
    that say what changed and why."""
    cfg = vocabulary()["retune"]
    params = default_params(task)
    for name, value in _ASSIGN.findall(previous_code):
        number = float(value)
        if name in params.temperatures:
            params.temperatures[name] = number
        elif name in params.weights:
            params.weights[name] = number
        elif name in ("stage_bonus", "success_bonus", "action_penalty"):
            setattr(params, name, number)
    if "np.tanh(" in previous_code:
        params.transform = "tanh"
    notes: list[str] = []
    reached: dict[int, bool] = {}
    widened: set[str] = set()
    for component, values in stats.items():
        match = _COMPONENT.match(component)
        if not match:
            continue
        k, term = int(match.group(1)), match.group(2)
        weight = params.weights.get(f"w_{term}_{k}")
        if weight is None:
            continue
        reached[k] = reached.get(k, False) or values["max"] > 1e-9
        temp = f"temp_{term}_{k}"
        if temp not in params.temperatures or values["max"] <= 1e-9 or weight <= 0:
            continue
        hi, lo = values["max"] / weight, values["min"] / weight
        if hi < cfg["dead_max"]:
            _scale(params.temperatures, temp, cfg["widen"], notes, "stays near zero: widened")
            widened.add(temp)
        elif lo > cfg["saturated_min"]:
            _scale(params.temperatures, temp, cfg["narrow"], notes, "always saturated: narrowed")
    unreached = sorted(k for k, hit in reached.items() if not hit)
    if unreached and unreached[0] > 0:
        k = unreached[0]
        for key in [w for w in params.weights if w.endswith(f"_{k}")]:
            _scale(params.weights, key, cfg["unreached_weight"], notes, f"stage {k} never reached")
        for key in [t for t in params.temperatures if t.endswith(f"_{k - 1}")]:
            if key not in widened:
                _scale(
                    params.temperatures, key, cfg["bottleneck_widen"], notes,
                    f"stage {k - 1} never completed: widened",
                )  # fmt: skip
    if success_rate == 0.0 and stats and not unreached:
        params.success_bonus *= cfg["success_bonus_factor"]
        notes.append(
            f"success_bonus -> {params.success_bonus:.3g}: every stage reached, no success"
        )
    t_lo, t_hi = cfg["temperature_range"]
    w_lo, w_hi = cfg["weight_range"]
    params.temperatures = {k: min(max(v, t_lo), t_hi) for k, v in params.temperatures.items()}
    params.weights = {k: min(max(v, w_lo), w_hi) for k, v in params.weights.items()}
    return params, notes


def _scale(table: dict[str, float], key: str, factor: float, notes: list[str], why: str) -> None:
    old = table[key]
    table[key] = old * factor
    notes.append(f"{key}: {old:.4g} -> {table[key]:.4g} ({why})")


def parse_feedback(feedback: str) -> tuple[str, float | None, dict[str, dict[str, float]]]:
    """(previous code, success rate, component stats) from a policy-feedback message."""
    code = fenced(feedback, "python") or ""
    rate = _SUCCESS_RATE.search(feedback)
    stats: dict[str, dict[str, float]] = {}
    for name, hi, mean, lo in _STAT.findall(feedback.split("```")[0]):
        if name.strip() == "component":
            continue
        values = {"max": float(hi), "mean": float(mean), "min": float(lo)}
        if all(math.isfinite(v) for v in values.values()):
            stats[name.strip()] = values
    return code, (float(rate.group(1)) if rate else None), stats


# ------------------------------------------------------------------------------ code
def render_code(task: TaskStructure, params: RewardParams, label: str) -> str:
    """The ``compute_reward`` source for ``task`` with ``params``."""
    vocab = vocabulary()
    transform = "np.exp(-d / {t})" if params.transform == "exp" else "1.0 - np.tanh(d / {t})"
    out = [
        f"# Staged reward for: {task.command or 'the described task'}",
        f"# Written by itskill's {BACKEND} (not a language model), {label}.",
        "import numpy as np",
        "",
        "",
        "def compute_reward(ctx):",
        '    """Staged shaping per subtask + stage bonus + success bonus - action penalty."""',
        '    stage = np.asarray(ctx["stage"]).astype(np.int64)',
        "    # Temperatures (metres or radians): one per transformed term.",
    ]
    for stage in task.stages:
        for name in stage.terms:
            term = vocab["terms"][name]
            if term["kind"] == "distance":
                var = f"temp_{name}_{stage.index}"
                doc = term["doc"].format(**stage.fields)
                out.append(f"    {var} = {params.temperatures[var]:.5g}  # {doc}")
    out.append("    # Term weights: a completed stage keeps paying its terms' full weight.")
    for stage in task.stages:
        for name in stage.terms:
            var = f"w_{name}_{stage.index}"
            out.append(f"    {var} = {params.weights[var]:.4g}")
    out += [
        f"    stage_bonus = {params.stage_bonus:.4g}",
        f"    success_bonus = {params.success_bonus:.4g}",
        f"    action_penalty = {params.action_penalty:.4g}",
        "",
        "    components = {}",
    ]
    for stage in task.stages:
        k, f = stage.index, stage.fields
        out.append(f"    # stage {k}: {stage.action} (object {f['i']}, recipe {stage.recipe})")
        for name in stage.terms:
            term = vocab["terms"][name]
            if term["kind"] == "distance":
                out.append(f"    d = {term['distance'].format(**f)}")
                out.append(f"    value = {transform.format(t=f'temp_{name}_{k}')}")
            else:
                out.append(f"    value = {term['value'].format(**f)}")
            if "gate" in term:
                out.append(f"    value = value * {term['gate'].format(**f)}")
            if "floor" in term:
                out.append(f"    value = np.maximum({term['floor'].format(**f)}, 0.9 * value)")
            out.append(
                f'    components["{k}.{stage.action}/{name}"] = w_{name}_{k} * '
                f"np.where(stage > {k}, 1.0, np.where(stage == {k}, value, 0.0))"
            )
    out += [
        f"    success = {task.success}",
        '    components["stage_bonus"] = stage_bonus * stage.astype(np.float64)',
        '    components["success"] = success_bonus * success.astype(np.float64)',
        '    motion = np.asarray(ctx["action"], dtype=np.float64)[:, :4]',
        '    components["action_penalty"] = -action_penalty * np.mean(motion**2, axis=-1)',
        "    total = sum(components.values())",
        "    return total, components",
        "",
    ]
    return "\n".join(out)


def _seed(*parts: object) -> int:
    digest = hashlib.sha256("|".join(str(p) for p in parts).encode()).hexdigest()
    return int(digest[:16], 16)


def synthesise(description: str, n: int, feedback: str | None = None) -> list[str]:
    """``n`` replies, each a short note and one ```python fence with a staged reward."""
    try:
        task = parse_description(description)
    except SynthesisError as err:
        return [f"The {BACKEND} cannot write a reward: {err}."] * n
    notes: list[str] = []
    if feedback is not None:
        code, rate, stats = parse_feedback(feedback)
        base, notes = retune(task, code, rate, stats)
    else:
        base = default_params(task)
    header = f"The {BACKEND} composed a staged reward for {len(task.stages)} stage(s)"
    if feedback is not None:
        header += " and retuned it from the policy feedback: " + (
            "; ".join(notes) if notes else "no change was called for"
        )
    replies = []
    for s in range(n):
        params = base if s == 0 else vary(base, _seed(description, feedback, s))
        label = f"sample {s}" + (" (retuned)" if feedback is not None else "")
        code = render_code(task, params, label)
        replies.append(f"{header}. Sample {s}.\n\n```python\n{code}```\n")
    return replies
