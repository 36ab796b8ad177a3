"""The offline task planner: a command matched to a catalogue task by rule.

1. Objects are grounded from the words of the command against the catalogue's object names
   (``nut_m12`` is "M12 nut", ``peg_rect_16mm`` "rectangular peg"); sizes may be written "M16",
   "16 mm" or "16mm", and a size or shape belongs to the part word nearest it. A bare "the
   nut" means the M12 nut and a bare "the peg" the round peg, and the plan's notes say so;
   "big"/"small" pick the largest/smallest; "nuts", "both", "each" or two sizes or shapes named
   mean every one named.
   Fixture words (bolt, hole) must match the task's fixtures; a size or shape the command gives
   one that the chosen task's lacks is noted.
2. The command is split into clauses ("pick up X", "place it on Y", "screw it down", ...); each
   clause's verb adds the actions that distinguish it (``pick`` -> grasp, lift; ``insert`` ->
   [place], insert; ...); a verb repeating the previous one's actions need not add them again.
   Clauses go in the order they are done: "after grasping it" comes before the verb it follows.
   "approach" (and "carry") are implied everywhere and not compared.
3. A catalogue task matches if its objects are the grounded ones and its distinguishing actions
   are exactly the clauses' (optional ones may be absent). Among matches, the one whose own
   command shares most words with the user's wins, less one per optional action it lacks; ties
   are broken as :func:`plan` explains (the part named, carrying or not, the verbs shared, the
   words added).
4. What the rules cannot read is refused, not dropped: a negation ("don't", "never", "without":
   a plan says only what to do), a clause between separators (commas, "and", "then", ...) with
   no verb they know that is more than filler or a part's description ("and then dance"), a
   place a part is put that is no fixture of the scene ("on the table"), and a part moved
   other than over or onto a fixture ("move the nut away from the bolt").
"""

from __future__ import annotations

import bisect
import json
import re
from collections.abc import Iterable
from dataclasses import dataclass

from itskill.llm.offline.backend import BACKEND

# What a verb acts on: "it", "them" or "the" and up to three words ("the held M12 nut").
_OBJ = r"(?:it |them |the (?:\w+ ){0,3})?"
# The verbs that carry a held part, a move of the part, and such a move somewhere.
_CARRYING = r"\bcarry\w*|\btransport\w*|\bbring\w*"
_MOVE_PART = r"\bmove\w* (?:it|them|the (?:\w+ ){0,2}(?:nut|peg)s?)"
# "Move the nut carefully over the bolt", "... back over ...", "... so it sits over the bolt".
_MOVE_PART_TO = (
    rf"{_MOVE_PART} (?:\w+ly |back |all the way |(?:so|until) (?:that )?(?:it|they) "
    r"(?:is|are|sits?) )?(?:over|above|to)\b"
)
_CARRY_VERB = rf"{_CARRYING}|\bhold\w*|{_MOVE_PART_TO}"
# A part moved up is lifted ("unscrew the nut and move it up", "... up off the bolt", "... up to
# a safe height"), unless on its way to a part, a fixture or a side ("move the nut up onto the
# bolt", "up and then over the bolt", "up so it sits on the bolt", "up to the left").
_MOVE_PART_UP = (
    rf"{_MOVE_PART} (?:\w+ly |straight |right |back )?(?:up|upwards?|higher)\b"
    r"(?!,?(?: \w+){0,4}? (?:over|above|onto|into|in|on|to|toward\w*|next to|near|beside|by)"
    r" (?:the |its |a |an )?(?:\w+ )?(?:bolt|hole|nut|peg|fixture|left|right|side)s?\b)"
)
# A carry that takes the part somewhere ("bring it to the bolt"; not "hold it", which keeps it).
_CARRY_TO = rf"{_CARRYING}|\bhold\w* {_OBJ}(?:over|above)\b|{_MOVE_PART_TO}"
_PLACE = ("place|align?",)  # the actions of the place verbs
_PLACES_FIRST = {"place?", "align"}  # a screw or insert places first; an align is a place's end
# verb phrase -> distinguishing actions; a "?" suffix marks an action that may be absent. Earlier
# patterns claim their words first: "position the gripper" is a move, not a place.
_VERBS: list[tuple[str, tuple[str, ...]]] = [
    (
        r"\b(?:position|put|set|lower|drop|place)\w* (?:the |your )?"
        r"(?:gripper|hand|fingers|arm|end effector)(?![-'\w])",  # not "the hand-held nut"
        (),
    ),
    (r"\bget (?:close|closer|near|next|to)\b", ()),
    (
        r"\bunscrew\w*|\bloosen\w*|\bunfasten\w*|\buntighten\w*|\bunthread\w*"
        rf"|\bscrew\w* {_OBJ}off\b",
        ("unscrew",),
    ),
    (
        # "thread" but not "threaded", which describes the nut of grasp_nut_*_bolt.
        r"\bscrew\w*|\btighten\w*|\bfasten\w*|\btwist\w*|\bthread(?:s|ing)?\b"
        r"|\b(?:turn|rotat)\w* (?:it|the (?:m\d+ )?nut)\b",
        ("place?", "screw"),
    ),
    (
        r"\binsert\w*|\bplug\w*|\bstick\w*|\bfit\b"
        rf"|\b(?:put|push|slide|press)\w* {_OBJ}(?:into\b|in\b(?! place\b))",
        ("place?", "insert"),
    ),
    (
        rf"\bpull\w*|\bremov\w*|\btake\w* {_OBJ}(?:out|off)\b|\bextract\w*",
        ("unscrew?", "grasp", "lift?"),
    ),
    (r"\bpick\w*|\bgrab\w*|\btake\w*|\bfetch\w*|\bget\b", ("grasp", "lift?")),
    (
        # "grip" but not "gripper"; holding something in the hand grasps it, holding it over a
        # fixture carries it.
        r"\bgrasp\w*|\bclamp\w*|\bclose\w* (?:the )?(?:fingers|gripper|hand)\b"
        rf"|\bgrip(?:s|ped|ping)?\b|\bhold\w* {_OBJ}(?:in|with) (?:the |your )?"
        r"(?:gripper|hand|fingers)\b",
        ("grasp",),
    ),
    (rf"\blift\w*|\braise\w*|{_MOVE_PART_UP}", ("grasp?", "lift")),
    (
        r"\bplace\w*|\bput\w*|\bset\w*|\bmount\w*|\bdrop\w*|\bposition\w*|\blower\w*"
        rf"|\bmove\w* {_OBJ}onto\b",
        _PLACE,
    ),
    (rf"\balign\w*|\borient\w*|\bline\w* {_OBJ}up\b", ("align",)),
    (r"\bpush\w*|\bslide\w*|\bshove\w*|\bnudge\w*", ("push",)),
    # Not "let go", a release.
    (r"\breach\w*|\bmove\w*|(?<!\blet )\bgo\b|\btouch\w*|\bapproach\w*|\bhover\w*", ()),
    (_CARRY_VERB, ()),
]
_IMPLIED = {"approach", "carry"}
# A word that puts the verb right after it out of the command's order ("after grasping it").
_ORDER_WORD = r"\b(after|before)\s+(?:you\s+(?:have\s+)?|having\s+)?$"
_ORDINALS = ["First", "Second", "Third", "Fourth", "Fifth", "Sixth", "Seventh", "Eighth", "Ninth",
             "Tenth", "Eleventh", "Twelfth"]  # fmt: skip
_SHAPES = {"round": "round", "cylindrical": "round", "circular": "round", "rect": "rect",
           "rectangular": "rect", "square": "rect", "box": "rect", "flat": "rect"}  # fmt: skip
_SMALL = {"small", "smaller", "smallest", "little", "thin", "thinner"}
_LARGE = {"big", "bigger", "biggest", "large", "larger", "largest", "thick", "thicker"}
_STOP = {"the", "a", "an", "it", "them", "and", "then", "of", "to", "on", "onto", "into", "in",
         "up", "its", "with", "please", "robot"}  # fmt: skip


@dataclass(frozen=True)
class Part:
    """A catalogue object or fixture name read as words: kind (nut, peg, bolt, hole) and tags."""

    name: str
    kind: str
    size: str  # "m12", "m16" or ""
    shape: str  # "round", "rect" or ""
    width: int  # millimetres: 12 for "m12", 16 for "16mm"; 0 if the name gives none

    @classmethod
    def from_name(cls, name: str) -> Part:
        tokens = name.lower().split("_")
        size = next((t for t in tokens if re.fullmatch(r"m\d+", t)), "")
        shape = next((_SHAPES[t] for t in tokens if t in _SHAPES), "")
        width = next((int(m[1]) for t in tokens if (m := re.fullmatch(r"m?(\d+)(?:mm)?", t))), 0)
        return cls(name, tokens[0], size, shape, width)

    @property
    def label(self) -> str:
        shape = {"round": "round", "rect": "rectangular"}.get(self.shape, "")
        return " ".join(w for w in (self.size.upper(), shape, self.kind) if w)


class PlanningError(ValueError):
    """The command cannot be grounded in the catalogue; the message says why."""


_WORD = r"[a-z0-9]+"


def _words(text: str) -> list[str]:
    return re.findall(_WORD, text.lower())


def _names_kind(words: Iterable[str], kinds: set[str]) -> bool:
    """Whether one of ``words`` names one of ``kinds`` ("bolt" or "bolts")."""
    return any(w.removesuffix("s") in kinds for w in words)


# "M16", "m 16", "16mm" and "16 mm" are 16 mm. A longer number is no part's size in millimetres,
# and int() refuses one of thousands of digits.
_NUMBER = r"\d{1,4}"


def _sizes_at(words: list[str]) -> list[tuple[int, int]]:
    """The sizes written in ``words``: (position of their first word, millimetres)."""
    found = []
    for i, word in enumerate(words):
        nxt = words[i + 1] if i + 1 < len(words) else ""
        if m := re.fullmatch(rf"m({_NUMBER})|({_NUMBER})mm", word):
            found.append((i, int(m[1] or m[2])))
        elif word == "m" and re.fullmatch(_NUMBER, nxt):
            found.append((i, int(nxt)))
        elif re.fullmatch(_NUMBER, word) and nxt == "mm":
            found.append((i, int(word)))
    return found


def _descriptors(command: str, kinds: set[str]) -> dict[str | None, tuple[set[int], set[str]]]:
    """The sizes (in millimetres) and shapes the command writes, by the part kind each describes:
    the kind whose word is nearest, the one after it on a tie ("the M16 nut and the round peg":
    16 is the nut's, round the peg's). Under None, those written with no kind word in the command.
    """
    words = _words(command)
    found: list[tuple[int, int | None, str | None]] = [  # (position, size, shape)
        *((i, mm, None) for i, mm in _sizes_at(words)),
        *((i, None, _SHAPES[w]) for i, w in enumerate(words) if w in _SHAPES),
    ]
    places = [(j, w.removesuffix("s")) for j, w in enumerate(words) if w.removesuffix("s") in kinds]
    out: dict[str | None, tuple[set[int], set[str]]] = {}
    for i, size, shape in found:
        owner = min(places, key=lambda p: (abs(p[0] - i), p[0] < i))[1] if places else None
        sizes, shapes = out.setdefault(owner, (set(), set()))
        if size is not None:
            sizes.add(size)
        if shape is not None:
            shapes.add(shape)
    return out


def _described(
    table: dict[str | None, tuple[set[int], set[str]]], kind: str, rivals: set[str]
) -> tuple[set[int], set[str]]:
    """The sizes and shapes a command gives a part of ``kind`` (``table``: its
    :func:`_descriptors`). One it gives no size (or shape) takes those written for kinds other
    than ``rivals``: "the peg into the rectangular hole" is the rectangular peg, "the M16 nut and
    the peg" not the 16 mm peg."""
    own_sizes, own_shapes = table.get(kind, (set(), set()))
    lent = [v for k, v in table.items() if k != kind and k not in rivals]
    return (
        own_sizes or set().union(*(sizes for sizes, _ in lent)),
        own_shapes or set().union(*(shapes for _, shapes in lent)),
    )


def _missing_size(command: str, parts: list[Part]) -> str | None:
    """Why the command cannot be grounded if it asks for a part in a size the scene does not
    have ("the M20 nut"): written just before the part's word, where it can only be the part's
    size ("lift the nut 30 mm" is a height); None otherwise."""
    words = _words(command)
    for kind in sorted({p.kind for p in parts if p.width}):
        places = [k for k, w in enumerate(words) if w == kind]
        written = {mm for i, mm in _sizes_at(words) if any(k - 2 <= i < k for k in places)}
        have = sorted((p for p in parts if p.kind == kind), key=lambda p: p.width)
        if written and not written & {p.width for p in have}:
            asked = " or ".join(f"{w} mm" for w in sorted(written))
            return f"this scene has no {asked} {kind}: its {kind}s are " + ", ".join(
                p.label for p in have
            )
    return None


def _ground_objects(
    command: str, parts: list[Part], table: dict[str | None, tuple[set[int], set[str]]]
) -> tuple[list[Part], list[str]]:
    """The objects the command names, and notes on the assumptions made; :class:`PlanningError`
    if it describes one that no part of its kind fits ("the round 16 mm peg")."""
    words = _words(command)
    kinds = sorted({p.kind for p in parts})
    words_set = set(words)
    notes: list[str] = []
    grounded: list[Part] = []
    for kind in kinds:
        plural = f"{kind}s" in words or ("both" in words and kind in words)
        if kind not in words and not plural:
            continue
        of_kind = [p for p in parts if p.kind == kind]
        named_sizes, named_shapes = _described(table, kind, set(kinds))
        sizes = {p.width for p in of_kind if p.width in named_sizes}
        shapes = {p.shape for p in of_kind if p.shape in named_shapes}
        # "the M12 nut and the M16 nut", "each nut": every one it names, not a default.
        counted = bool({"each", "every", "two"} & words_set)
        plural = plural or len(sizes) > 1 or len(shapes) > 1 or counted
        chosen = [
            p for p in of_kind
            if (not sizes or p.width in sizes) and (not shapes or p.shape in shapes)
        ]  # fmt: skip
        if not chosen:
            raise PlanningError(
                f"no {kind} of this scene is as the command describes it: its {kind}s are "
                + ", ".join(p.label for p in of_kind)
            )
        relative = {w for w in words if w in _SMALL or w in _LARGE}
        if not plural and len(chosen) > 1 and relative:
            # "the big nut": the largest of those the command could mean.
            chosen = [sorted(chosen, key=lambda p: p.width, reverse=bool(relative & _LARGE))[0]]
        if not plural and len(chosen) > 1:
            default = sorted(chosen, key=lambda p: (p.size or "~", p.shape != "round", p.name))[0]
            notes.append(
                f"'the {kind}' names no size or shape: assumed the {default.label} "
                f"(others: {', '.join(p.label for p in chosen if p is not default)})"
            )
            chosen = [default]
        grounded += sorted(chosen, key=lambda p: p.name)
    return grounded, notes


def _verb_hits(text: str) -> list[tuple[int, int, int]]:
    """The verbs of ``text`` (lower case) as written: (start, end, index in :data:`_VERBS`)."""
    hits: list[tuple[int, int, int]] = []
    for k, (pattern, _) in enumerate(_VERBS):
        for match in re.finditer(pattern, text):
            start, end = match.span()
            if any(s < end and start < e for s, e, _ in hits):
                continue  # "unscrew" already matched; do not read "screw" in it again
            hits.append((start, end, k))
    return sorted(hits)


def _clauses(command: str) -> list[tuple[str, ...]]:
    """The distinguishing actions of each verb in the command, in the order they are done."""
    text = command.lower()
    hits = [(start, _VERBS[k][1]) for start, _, k in _verb_hits(text)]
    ordered = [actions for _, actions in hits]
    # "lift the peg after grasping it" grasps first, and so does "before lifting the peg, grasp
    # it": a verb introduced by "after" swaps with the verb before it, and a first verb introduced
    # by "before" with the one after it.
    for k, (start, _) in enumerate(hits):
        marker = re.search(_ORDER_WORD, text[:start])
        if marker and marker[1] == "after" and k > 0:
            ordered[k - 1], ordered[k] = ordered[k], ordered[k - 1]
        elif marker and marker[1] == "before" and k == 0 and len(ordered) > 1:
            ordered[0], ordered[1] = ordered[1], ordered[0]
    clauses: list[tuple[str, ...]] = []
    for k, actions in enumerate(ordered):
        # "Grab the peg and pull it out" grasps once: a verb repeating the previous one's
        # actions may add them again, but need not.
        before = {a.rstrip("?") for a in clauses[-1]} if clauses else set()
        if actions == _PLACE and not any(_PLACES_FIRST & set(later) for later in ordered[k + 1 :]):
            # A place is optional only where a later verb places first ("place the nut on the
            # bolt and screw it down"); otherwise "unscrew the nut and place it" was planned as
            # the unscrew alone.
            actions = tuple(a.rstrip("?") for a in actions)
        clauses.append(
            tuple(a + "?" if a in before and not a.endswith("?") else a for a in actions)
        )
    return clauses


_PLACE_WORDS = {"on", "onto", "into", "in", "over", "above", "to", "next", "near", "beside",
                "from", "off", "out", "of", "by", "at", "toward", "towards"}  # fmt: skip


def _acted_on(command: str, kinds: set[str]) -> bool:
    """Whether the command names a part of one of ``kinds`` as what a verb acts on ("pick up
    the bolt"), not as a place ("on the bolt", "out of the hole": a word of place within the
    three words before it)."""
    words = _words(command)
    return any(
        w.removesuffix("s") in kinds and not _PLACE_WORDS & set(words[max(0, j - 3) : j])
        for j, w in enumerate(words)
    )


# Words that say what the robot must not do. A plan is a list of things to do, so the rules read
# a command with one as if it were not there ("don't pick up the nut" was the pick). Whole words:
# "nothing", "knot" and "another" say no "not", but "cannot" is one word, and "don't", "can't"
# end in "n't".
_NEGATION = (
    r"\b(?:not|never|without|cannot|nor|neither|dont|doesnt|cant|wont|shouldnt|mustnt|avoid\w*)\b"
    r"|\b\w+n['’]t\b|\binstead of\b|\brather than\b"
)
# What separates the clauses of a command: punctuation, and the words that join or order them
# (as :func:`_clauses` reads "after" and "before"). Not a colon: "Assemble the nut onto the bolt:
# pick it up, ..." says after it how.
_CLAUSE_SEP = r"[,;.!?]|\b(?:and|then|but|after|before)\b"
_KNOWN_ACTIONS = "pick up, place, screw, unscrew, insert, pull out, push, lift, move to"
# Words a clause with no verb may be made of: manners, politeness, who does it and when ("the
# robot should", "carefully", "then"), and how a part is described ("the M16 nut on its bolt",
# "the held one"). Anything else in such a clause is something to do that the rules do not know.
_UNITS = {"mm", "cm", "m", "millimetres", "millimeters", "centimetres", "centimeters"}
_FILLER = _UNITS | {
    "please", "kindly", "now", "first", "second", "third", "next", "last", "afterwards",
    "afterward", "also", "just", "again", "too", "so", "ok", "okay", "thanks", "thank", "you",
    "i", "we", "me", "us", "robot", "arm", "should", "must", "can", "could", "would", "will",
    "shall", "may", "want", "need", "like", "for", "is", "are", "be", "do", "all", "way",
    "right", "away", "yes", "hey", "hi", "or", "as", "well", "one", "ones", "this", "that",
    "these", "those", "there", "here", "down", "your", "my", "our", "their", "gripper", "hand",
    "fingers", "finger", "end", "effector", "same", "time", "both", "each", "every", "two",
    "held", "threaded", "standing", "sitting", "lying", "tight", "fast", "possible", "if",
    "necessary", "needed", "sure", "make", "nothing", "else",
    # "..., then let go": a place ends with the fingers open ("go" is a verb elsewhere).
    "let", "go",
}  # fmt: skip
# A clause that starts so describes a part ("..., which is on the bolt") and does nothing.
# Not "that": "and after that fly to the moon" does something.
_RELATIVE = {"which", "who", "where", "whose"}
# Where a verb puts a part. Those of _TOWARD always say it ("take it to the shelf"); those of _AT
# only after a verb that puts or moves a part: "pick up the nut on the table" says where it is.
_TOWARD = {"to", "onto", "into", "toward", "towards"}
_AT = {"on", "upon", "in", "inside", "over", "above", "at", "next", "near", "beside", "atop",
       "under", "below", "beneath", "behind", "against", "between", "close", "closer"}  # fmt: skip
# The verbs that put or move a part somewhere (place, screw, insert, align, push, carry).
_PUTTING = {
    k for k, (pattern, actions) in enumerate(_VERBS)
    if pattern == _CARRY_VERB
    or {a.rstrip("?") for a in actions} & {"place|align", "align", "insert", "screw", "push"}
}  # fmt: skip
# "Move" is a reach ("move to the nut") but with a part after it moves the part, as
# :data:`_CARRY_VERB` reads "move it over": "move the nut under the table" puts it there.
_MOVES_PART = rf"{_MOVE_PART}\b"
# Words a place may end in that are no place of their own: "on top of the bolt", "screw it to the
# bottom", "in place", "push it to the left", "into the round one", "lift it up to 30 mm".
_NOT_A_PLACE = {"top", "bottom", "front", "back", "side", "middle", "centre", "center", "end",
                "edge", "entrance", "left", "right", "place", "position", "way", "height",
                "gripper", "hand", "fingers", "effector", "robot", "it", "them", "one", "ones",
                "here", "there",
                # How or when, not where: "at once", "in one motion", "in the correct orientation"
                # ("orient" is a verb, so the place's words stop before it).
                "once", "go", "motion", "movement", "moment", "time", "turn", "turns", "step",
                "steps", "order", "sequence", "manner", "fashion", "orientation", "correct",
                "proper", "angle", "pose", "speed", "rate"} | _UNITS  # fmt: skip
# Words that end the words of a place: another word of place ("on top of the bolt" reads on
# through "of"), one of how or when ("to the left now"), or one that starts a verb phrase ("I want
# you to, if you can, ...").
_PLACE_END = ((_TOWARD | _AT | _PLACE_WORDS) - {"of"}) | {
    "with", "along", "past", "through", "across", "around", "beyond", "via", "until", "while",
    "using", "for", "as", "so", "please", "now", "again", "too", "first", "then", "thanks", "fast",
    "up", "down", "you", "i", "we", "me", "us", "can", "could", "should", "must", "would",
    "will", "shall", "may", "might", "if", "is", "are", "be", "do",
}  # fmt: skip
# Where a part might be that this scene has none of: "the nut on the shelf" is not the nut on the
# table. Only these are refused where a phrase says where a part is, not where it goes: such a
# phrase names the part's own features too ("at its base", "in front of you").
_ELSEWHERE = {"shelf", "shelves", "drawer", "box", "boxes", "tray", "bin", "cabinet", "floor",
              "ground", "rack", "cupboard", "container", "basket", "bowl", "cup", "plate",
              "counter", "conveyor", "pallet", "crate", "bag", "pocket"}  # fmt: skip
# The verbs that only move the hand: reach, move to, go, hover, position the gripper.
_HAND_ONLY = {k for k, (pattern, actions) in enumerate(_VERBS) if not actions} - {
    k for k, (pattern, _) in enumerate(_VERBS) if pattern == _CARRY_VERB
}
# Words that stand for a part or place named elsewhere in the command: "go to it", "move over the
# M16 one", "go there".
_PRONOUNS = {"it", "them", "one", "ones", "there", "this", "that"}
# A hand move up or down is part of the lift or place beside it ("pick up the nut and move up").
_VERTICAL = {"up", "upward", "upwards", "higher", "down", "downward", "downwards", "lower"}
# Where a hand move goes that is no part of the scene: "then go home", "move back".
_NOWHERE = {"home", "back", "away", "start", "origin", "rest", "neutral", "idle", "initial",
            "beginning", "aside"}  # fmt: skip
_DESCRIBING = _FILLER | _STOP | _PLACE_WORDS | _TOWARD | _AT | _SMALL | _LARGE | set(_SHAPES)


def _adverb(word: str) -> bool:
    """Whether ``word`` reads as an adverb of manner ("carefully", "gently"; not "fly")."""
    return len(word) >= 6 and word.endswith("ly")


def _size_word(word: str) -> bool:
    """Whether ``word`` is a size or a number ("m16", "16mm", "30")."""
    return re.fullmatch(rf"m?{_NUMBER}(?:mm)?|\d+", word) is not None


def _negation(command: str) -> str | None:
    """Why the command cannot be planned if it says what not to do; None otherwise."""
    found = re.search(_NEGATION, command.lower())
    if found is None:
        return None
    return (
        f"the offline planner cannot plan what not to do ({found[0]!r}): say only what the "
        "robot should do"
    )


def _segments(text: str) -> list[tuple[str, list[tuple[int, str]], list[tuple[int, int, int]]]]:
    """The clauses of ``text`` (lower case) between :data:`_CLAUSE_SEP` separators, each as its
    text (first word to last), its words with their positions in ``text`` and its
    :func:`_verb_hits`; those with no word are left out."""
    bounds = [0]
    for sep in re.finditer(_CLAUSE_SEP, text):
        bounds += [sep.start(), sep.end()]
    bounds.append(len(text))
    hits = _verb_hits(text)
    starts = [start for start, _, _ in hits]
    segments = []
    for start, end in zip(bounds[::2], bounds[1::2], strict=True):
        words = [(m.start() + start, m[0]) for m in re.finditer(_WORD, text[start:end])]
        if words:
            # A verb belongs to the clause it starts in.
            own = hits[bisect.bisect_left(starts, start) : bisect.bisect_left(starts, end)]
            clause = text[words[0][0] : words[-1][0] + len(words[-1][1])]
            segments.append((clause, words, own))
    return segments


def _unplanned_clause(command: str, kinds: set[str]) -> str | None:
    """Why the command cannot be planned if one of its clauses has no verb the rules know and is
    more than filler or a part's description ("pick up the nut and then dance": the dance was
    dropped); None otherwise. ``kinds``: the scene's part and fixture kinds."""
    for clause, words, verbs in _segments(command.lower()):
        if verbs or words[0][1] in _RELATIVE:
            continue
        unknown = [
            w for _, w in words
            if w not in _DESCRIBING and w.removesuffix("s") not in kinds
            and not _adverb(w) and not _size_word(w)
        ]  # fmt: skip
        if unknown:
            return (
                f"the offline planner knows no action in {clause!r} and would drop it (it knows "
                f"{_KNOWN_ACTIONS}): say only what the robot should do"
            )
    return None


def _place_phrases(
    words: list[tuple[int, str]], verbs: list[tuple[int, int, int]], kinds: set[str]
) -> list[tuple[str, str, bool]]:
    """The places one clause writes, each as (the words, their kind, whether they name a part or
    fixture of the scene). Kind: ``"to"`` where a part goes ("to the shelf"), ``"at"`` where a
    part goes or is ("on the table"), ``"from"`` where a part is taken from ("from", "off" or
    "out of the drawer"). Words that name no place ("screw it on", "at once", "to the left") are
    left out."""
    places = []
    for i, (_, word) in enumerate(words):
        # "next to", "close to": a word of _AT, however "to" ends it.
        at_to = word in _TOWARD and i > 0 and words[i - 1][1] in _AT
        kind = "at" if word in _AT or at_to else "to" if word in _TOWARD else "from"
        if kind == "from" and word not in ("from", "off", "out"):
            continue
        # The place's words: up to six, to the next word of place, verb or manner ("to line up
        # with the hole" has none; "on top of the table" reads on through "of").
        phrase = []
        for pos, w in words[i + 1 : i + 7]:
            if w in _PLACE_END or _adverb(w) or any(s <= pos < e for s, e, _ in verbs):
                break
            phrase.append(w)
        if not phrase or phrase[-1] in _NOT_A_PLACE or _size_word(phrase[-1]):
            continue
        written = " ".join([words[i - 1][1]] * at_to + [word, *phrase])
        places.append((written, kind, _names_kind(phrase, kinds)))
    return places


def _unknown_place(command: str, kinds: set[str], places: list[Part]) -> str | None:
    """Why the command cannot be planned if it puts a part somewhere that is no fixture of the
    scene ("place it on the table" was placed on the bolt), or takes one from somewhere the scene
    does not have ("reach the nut on the shelf" reached the nut on the table); None otherwise.
    ``kinds``: the scene's part and fixture kinds; ``places``: its fixtures."""
    text = command.lower()
    labels = ", ".join(p.label for p in places)
    for clause, words, verbs in _segments(text):
        putting = any(v in _PUTTING for _, _, v in verbs) or bool(re.search(_MOVES_PART, clause))
        phrases = _place_phrases(words, verbs, kinds)
        for k, (written, kind, in_scene) in enumerate(phrases):
            if in_scene:
                continue  # "on its bolt", "screw on the nut", "from the hole"
            # After a verb that puts a part, "on ..." is where it goes, unless a "to ..." after
            # it says that ("put the nut that is on the table onto the bolt").
            goes = kind == "to" or (
                kind == "at" and putting and not any(kd == "to" for _, kd, _ in phrases[k + 1 :])
            )
            if goes:
                return f"{written!r} is no place of this scene: its places are the {labels}"
            if any(w in _ELSEWHERE or w.removesuffix("s") in _ELSEWHERE for w in written.split()):
                return (
                    f"{written!r} is nowhere in this scene: the parts start on the table, and "
                    f"its places are the {labels}"
                )
    return None


def _aimless_move(command: str, kinds: set[str]) -> str | None:
    """Why the command cannot be planned if a clause only moves the hand and names nothing of
    the scene to move to ("..., then go home" was dropped); None otherwise. A move that leads
    into the next clause ("go and get the nut", "reach out and grab it") is let through unless
    it says where else it goes ("move back and ...")."""
    segments = _segments(command.lower())
    for k, (clause, words, verbs) in enumerate(segments):
        if not _hand_only(verbs):
            continue
        said = {w for _, w in words}
        if _names_kind(said, kinds) or said & _PRONOUNS:
            continue
        if (k + 1 < len(segments) or said & _VERTICAL) and not said & _NOWHERE:
            continue
        return (
            f"{clause!r} moves the hand to nothing of this scene: the offline planner moves it "
            'only to a part or fixture ("move to the nut")'
        )
    return None


def _part_moved_nowhere(
    command: str, kinds: set[str], clauses: list[tuple[str, ...]]
) -> str | None:
    """Why the command cannot be planned if a clause moves a part with a verb that only moves
    the hand, and not over or to a part or fixture ("move the nut away from the bolt" and "move
    the nut to the left" were planned as a reach of the nut); None otherwise. A move down, or up
    on the way somewhere, is the lift or place of another clause ("pick up the nut and move it
    up higher"), if it has one and the move names no part or fixture ("... move it up over the
    hole" is refused); a move up alone is a lift (:data:`_MOVE_PART_UP`).
    ``kinds``: the scene's part and fixture kinds; ``clauses``: its :func:`_clauses`."""
    lifts_or_places = any(
        a.rstrip("?") in ("lift", "place", "place|align")  # a screw or insert places first
        for actions in clauses
        for a in actions
    )
    for clause, words, verbs in _segments(command.lower()):
        moved = re.search(_MOVES_PART, clause)
        if not _hand_only(verbs) or not moved:
            continue
        toward = re.search(_MOVE_PART_TO, clause)
        if toward and _names_kind(_words(clause[toward.end() :]), kinds):
            continue  # "move the nut over the bolt", "move it to the nut"
        named = _names_kind(_words(clause[moved.end() :]), kinds)
        if lifts_or_places and {w for _, w in words} & _VERTICAL and not named:
            continue  # "pick up the nut and move it up": not "... move it up over the hole"
        return (
            f"{clause!r} moves a part where the offline planner cannot take it: it moves a "
            'part over a fixture ("move the nut over the bolt") or onto it ("move the nut '
            'onto the bolt")'
        )
    return None


def _hand_only(verbs: list[tuple[int, int, int]]) -> bool:
    """Whether a clause's verbs (:func:`_verb_hits`) are there and only move the hand."""
    return bool(verbs) and all(v in _HAND_ONLY for _, _, v in verbs)


def _verb_groups(command: str) -> set[int]:
    """The :data:`_VERBS` entries a command uses."""
    text = command.lower()
    return {k for k, (pattern, _) in enumerate(_VERBS) if re.search(pattern, text)}


def _carries(command: str) -> bool:
    return re.search(_CARRY_VERB, command.lower()) is not None


def _skipped(pattern: list[str], actions: list[str]) -> int | None:
    """How few optional elements ``actions`` must skip to fit ``pattern`` (``a?`` optional,
    ``a|b`` alternatives); None if they do not fit."""
    # fewest[j]: the fewest skips fitting the pattern's tail read so far to actions[j:]. Filled
    # from the pattern's end, one element at a time, so a pattern of any length (a long command
    # repeats its clauses) takes len(pattern) * len(actions) steps and no recursion.
    fewest: list[int | None] = [None] * len(actions) + [0]
    for head in reversed(pattern):
        options = head.rstrip("?").split("|")
        optional = head.endswith("?")
        row: list[int | None] = []
        for j in range(len(actions) + 1):
            best = fewest[j + 1] if j < len(actions) and actions[j] in options else None
            skip = fewest[j]
            if optional and skip is not None and (best is None or skip + 1 < best):
                best = skip + 1
            row.append(best)
        fewest = row
    return fewest[0]


def plan(command: str, catalogue: list[dict]) -> dict:
    """The plan reply for ``command`` (see the planner prompt), or ``{"error": ...}``."""
    objects = {name for entry in catalogue for name in entry["objects"]}
    fixtures = {name for entry in catalogue for name in entry["fixtures"]}
    parts = [Part.from_name(n) for n in sorted(objects)]
    fixture_parts = [Part.from_name(n) for n in sorted(fixtures)]
    missing = _missing_size(command, parts + fixture_parts)
    if missing:
        return {"error": missing}
    table = _descriptors(command, {p.kind for p in parts + fixture_parts})
    try:
        grounded, notes = _ground_objects(command, parts, table)
        # A command may name only a fixture ("move the gripper over the M12 bolt"): match tasks
        # on their fixtures then.
        by_fixture = not grounded
        if by_fixture:
            grounded, notes = _ground_objects(command, fixture_parts, table)
    except PlanningError as err:
        return {"error": str(err)}
    words = set(_words(command))
    if not grounded:
        # The caller's error line goes on with the objects and fixtures it knows.
        return {"error": "the command names no object of this scene"}
    clauses = _clauses(command)
    if not clauses:
        return {"error": f"the command has no action this robot can do ({_KNOWN_ACTIONS})"}
    if by_fixture and any(clauses) and _acted_on(command, {p.kind for p in grounded}):
        # A fixture is where a part goes ("put it on the bolt": the nut's place), never what
        # is moved: "pick up the bolt" was planned as the nut's pick.
        labels = " and ".join(p.label for p in grounded)
        return {
            "error": f"the command names only the {labels}, a fixture, which stays where it "
            f"is: name the part to act on ({', '.join(p.label for p in parts)})"
        }
    # The rules match what the command says to do, so what they would not read is refused, not
    # dropped: a "not", a clause with no verb they know, a place the scene does not have.
    scene_kinds = {p.kind for p in parts + fixture_parts}
    unread = (
        _negation(command)
        or _unplanned_clause(command, scene_kinds)
        or _unknown_place(command, scene_kinds, fixture_parts)
        or _aimless_move(command, scene_kinds)
        or _part_moved_nowhere(command, scene_kinds, clauses)
    )
    if unread:
        return {"error": unread}
    carries = _carries(command)
    verb_groups = _verb_groups(command)
    named_fixtures = {p.kind for p in fixture_parts if p.kind in words or f"{p.kind}s" in words}
    per_object = [a for clause in clauses for a in clause]
    if len(grounded) > 1 and per_object and per_object[0].startswith("place"):
        # "Put each nut on its bolt": the nuts start on the table, so putting them is a pick first.
        per_object = ["grasp?", "lift?", *per_object]
    pattern = per_object * (len(grounded) if len(grounded) > 1 else 1)
    wanted = {p.name for p in grounded}
    candidates = []
    for entry in catalogue:
        if set(entry["fixtures"] if by_fixture else entry["objects"]) != wanted:
            continue
        if named_fixtures - {Part.from_name(f).kind for f in entry["fixtures"]}:
            continue
        # A command's verbs name the skills' steps; a catalogue without them has only stages.
        distinctive = [a for a in entry.get("steps", entry["actions"]) if a not in _IMPLIED]
        skipped = _skipped(pattern, distinctive)
        if skipped is not None:
            own = set(_words(entry["command"]))
            overlap = len((words - _STOP) & (own - _STOP))
            # Ties on shared words, in this order: a task whose command does not name its part
            # (hovering over the bolt) loses to one that does ("move the nut over the bolt"
            # carries it); reaching and carrying are both one approach, so "reach for the nut"
            # goes to the task that carries only if the user's command does; then the task whose
            # command uses more of the user's verbs ("lift the nut" is a lift, not a pick); then
            # the one adding fewer words the user did not say ("lift the peg" off the table,
            # not "lift the held peg out of its hole").
            unnamed = not by_fixture and not any(
                Part.from_name(o).kind in own for o in entry["objects"]
            )
            carry_mismatch = _carries(entry["command"]) != carries
            shared_verbs = len(verb_groups & _verb_groups(entry["command"]))
            unsaid = len(own - _STOP - words)
            key = (skipped - overlap, unnamed, carry_mismatch, -shared_verbs, unsaid, skipped)
            candidates.append((*key, entry["task"], entry))
    if not candidates:
        labels = " and ".join(p.label for p in grounded)
        read = ", ".join(a.rstrip("?").replace("|", " or ") for a in pattern)
        return {
            "error": f"no catalogue task does what the command asks with the {labels} "
            f"(actions read from the command: {read or 'move to'})"
        }
    entry = min(candidates, key=lambda c: c[:-1])[-1]
    actions = entry.get("steps", entry["actions"])
    grasp = actions.index("grasp") if "grasp" in actions else None
    if (
        re.search(_CARRY_TO, command.lower())
        and grasp is not None
        and "approach" not in actions[grasp:]
    ):
        # "Pick up the nut and move it over the bolt" was planned as the pick: no task picks a
        # part up and then only carries it.
        return {
            "error": f"no catalogue task carries the part after picking it up (the closest, "
            f'{entry["task"]!r}, would drop the carry): carry a part already held ("carry the '
            'M12 nut over the bolt") or put it down there ("... and place it on the bolt")'
        }
    for fixture in (Part.from_name(f) for f in entry["fixtures"]):
        if fixture.kind not in named_fixtures:
            continue
        named_sizes, named_shapes = _described(table, fixture.kind, {p.kind for p in fixture_parts})
        if (named_sizes and fixture.width not in named_sizes) or (
            named_shapes and fixture.shape not in named_shapes
        ):
            # "the M16 nut on the M12 bolt": a part goes into the fixture it fits.
            notes.append(f"the {fixture.kind} the command names is not this task's: it uses the "
                         f"{fixture.label}")  # fmt: skip

    notes.append(f"planned by the {BACKEND} (not a language model): matched catalogue task "
                 f"{entry['task']!r}")  # fmt: skip
    return {
        "task": entry["task"],
        "subtasks": subtasks(entry),
        "actions": list(entry["actions"]),
        "objects": list(entry["objects"]),
        "notes": "; ".join(notes),
    }


def subtasks(entry: dict) -> list[str]:
    """One "First, ..." sentence per action of a catalogue entry."""
    objects = [Part.from_name(n) for n in entry["objects"]]
    fixtures = [Part.from_name(n) for n in entry["fixtures"]] or [Part("", "table", "", "")]
    sentences = []
    # A command that starts by carrying, placing, inserting or lifting finds the part in hand.
    held = bool(re.match(r"\s*(carry|place|put|insert|lift|align)", entry["command"].lower()))
    slot = 0
    for k, action in enumerate(entry["actions"]):
        obj = objects[min(slot, len(objects) - 1)]
        fix = fixtures[min(slot, len(fixtures) - 1)]
        o, f = f"the {obj.label}", f"the {fix.label}"
        if action == "approach":
            text = f"carry {o} over {f}" if held else f"move the gripper to {o}"
        elif action == "carry":
            text = f"carry {o} over {f}"
        elif action == "grasp":
            text, held = f"close the gripper on {o}", True
        elif action == "lift":
            text = f"lift {o}" + (f" off {f}" if entry["actions"][0] == "unscrew" else "")
        elif action == "place":
            text = (
                f"place {o} on {f}" if fix.kind == "bolt" else f"place {o} at the entrance of {f}"
            )
            held = False
            slot += 1 if len(objects) > 1 else 0
        elif action == "align":
            text = f"align {o} with {f}"
        elif action == "insert":
            text = f"insert {o} into {f}"
        elif action == "screw":
            text = f"screw {o} down to the bottom of {f}"
        elif action == "unscrew":
            text, held = f"unscrew {o} from {f}", True
        elif action == "push":
            text = f"push {o} next to {f}"
        elif action == "release":
            text, held = f"open the gripper to release {o}", False
        else:
            text = f"{action} {o}"
        ordinal = _ORDINALS[k] if k < len(_ORDINALS) else f"Step {k + 1}"
        sentences.append(f"{ordinal}, {text}.")
    return sentences


def reply(command: str | None, catalogue_text: str | None) -> str:
    """The planner's reply text: one ```json fence."""
    if command is None or catalogue_text is None:
        result = {"error": f"{BACKEND}: the prompt has no <command> or <catalogue> block"}
    else:
        try:
            catalogue = json.loads(catalogue_text)
            result = plan(command, catalogue)
        except (ValueError, KeyError, TypeError) as err:
            result = {"error": f"{BACKEND}: cannot read the catalogue: {err}"}
    return "```json\n" + json.dumps(result, indent=1) + "\n```\n"
