"""Taking the reward code out of a model's reply."""

from __future__ import annotations

import pytest

from itskill.reward.generator import extract_code

CODE = "def compute_reward(ctx):\n    if ctx:\n        return 1\n    return 0"
FENCE = "```"


@pytest.mark.parametrize(
    ("reply", "why"),
    [
        (f"Here it is:\n{FENCE}python\n{CODE}\n{FENCE}\nDone.", "a python block"),
        (f"{FENCE}\n{CODE}\n{FENCE}", "an untagged block"),
        (f"{FENCE}python\nx = 1\n{FENCE}\n{FENCE}python\n{CODE}\n{FENCE}", "the block defining it"),
        (CODE, "bare code"),
        (f"{FENCE}python\n{CODE}", "a block cut off by the token limit"),
        (f"{FENCE}python\n{CODE}{FENCE}", "a fence closed at the end of the last code line"),
        (f"Here is the reward: {FENCE}python\n{CODE}\n{FENCE}", "a fence opened after text"),
        (f"Use {FENCE}np.where{FENCE} to gate.\n{FENCE}python\n{CODE}\n{FENCE}", "inline"),
        # Each of these ended in a syntax error in the sandbox, costing a regeneration.
        (
            "1. The reward:\n   "
            + FENCE
            + "python\n"
            + "\n".join("   " + line for line in CODE.splitlines())
            + "\n   "
            + FENCE,
            "a block indented in a list item",
        ),
        (f"Sure:\r\n{FENCE}python\r\n{CODE}\r\n{FENCE}\r\n".replace("\n    ", "\r\n    "), "CRLF"),
        (f"{FENCE}python title=reward.py\n{CODE}\n{FENCE}", "text after the language tag"),
        (
            f"{FENCE}diff\n- def compute_reward(ctx): old\n{FENCE}\n{FENCE}python\n{CODE}\n{FENCE}",
            "a diff of the change before the code",
        ),
        (f"~~~python\n{CODE}\n~~~", "a tilde fence"),
        (
            f"````markdown\nThe reward:\n{FENCE}python\n{CODE}\n{FENCE}\nTry it.\n````",
            "a python block in a markdown block",
        ),
        (f"~~~md\nThe reward:\n{FENCE}python\n{CODE}\n{FENCE}\n~~~", "in a tilde markdown block"),
        # Read as untagged code, fences and all: a syntax error for the sandbox.
        (f"````\nHere:\n{FENCE}python\n{CODE}\n{FENCE}\n````", "in an untagged wrapper"),
    ],
)
def test_the_code_is_found(reply: str, why: str) -> None:
    assert extract_code(reply) == CODE, why


def test_a_python_block_without_compute_reward_is_taken_before_the_whole_reply() -> None:
    assert extract_code(f"Words.\n{FENCE}python\nx = 1\n{FENCE}") == "x = 1"


@pytest.mark.parametrize("fence", [f"{FENCE}python", FENCE, "````"])
def test_a_line_of_tildes_in_python_code_is_no_fence(fence: str) -> None:
    code = f'"""Reward.\n~~~~~~~\n"""\n\n{CODE}'
    assert extract_code(f"{fence}\n{code}\n{fence.rstrip('python')}") == code


@pytest.mark.parametrize("expr", ["-" * 200_000 + "1", "1+" * 200_000 + "1"])
def test_a_wrapper_nested_past_the_parser_is_no_crash(expr: str) -> None:
    # Asking whether an untagged wrapper is Python raised MemoryError or RecursionError.
    code = f"def compute_reward(ctx):\n    return {expr}"
    assert extract_code(f"````\n{code}\n````") == code


def test_a_reply_of_fences_nested_a_thousand_deep_is_no_crash() -> None:
    # Each Markdown block was read for the blocks inside it, one call deeper: RecursionError,
    # which a resumed search met again on the cached reply.
    opens = [("~" if i % 2 == 0 else "`") * (3 + (1000 - i) // 2) for i in range(1000)]
    reply = "\n".join(f + "md" for f in opens) + f"\n{FENCE}python\n{CODE}\n{FENCE}\n"
    reply += "\n".join(reversed(opens))
    assert isinstance(extract_code(reply), str)  # the probe then says it is no reward


def test_a_reply_ending_in_a_long_run_of_fence_characters_is_read_quickly() -> None:
    # The opening fence's pattern backtracked over the run: 0.55 s at 40,000 characters,
    # quadratic beyond.
    import time

    start = time.perf_counter()
    for char in "`~":
        assert extract_code(f"{FENCE}python\n{CODE}\n{FENCE}\n" + char * 200_000) == CODE
    assert time.perf_counter() - start < 1.0
