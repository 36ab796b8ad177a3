"""Transfer settings: the packaged defaults and clear errors for a bad file."""

from __future__ import annotations

from pathlib import Path

import pytest

from itskill.transfer import TransferConfig, TransferConfigError, load_transfer_config


def test_packaged_defaults_are_the_dataclass_defaults() -> None:
    assert load_transfer_config() == TransferConfig()


@pytest.mark.parametrize(
    "text,where,problem",
    [
        # Range errors named "values" and the Python field (pst_keep), not the file's key.
        ("[attention]\nprior_weight = 1.5\n", "attention.prior_weight", r"expected in \[0, 1\]"),
        ("[attention]\nhidden = 'wide'\n", "attention.hidden", "expected an integer"),
        ("[fusion]\nhidden = [64, 'x']\n", "fusion.hidden", "list of integers"),
        ("[sources]\ntop = 3\n", "sources.top", "unknown field; expected one of"),
        ("[pst]\nkeep = 0\n", "pst.keep", "expected at least 1, got 0"),
        ("[attention]\nhidden = 0\n", "attention.hidden", "expected at least 1, got 0"),
        ("[analyzer]\nretries = -1\n", "analyzer.retries", "expected 0 or more, got -1"),
        ("[sources]\nk = 0\n", "sources.k", "expected at least 1"),
        ("[sources]\nmin_success = 2\n", "sources.min_success", r"expected in \[0, 1\]"),
        ("[fusion]\nhidden = [64, 0]\n", "fusion.hidden", "expected positive widths"),
        # Not finite: nan passed every range check that compares.
        ("[sources]\nmin_success = nan\n", "sources.min_success", "expected a finite number"),
        ("[attention]\nprior_weight = inf\n", "attention.prior_weight", "a finite number"),
        ("[head]\nresidual = 'yes'\n", "head.residual", "expected"),
        ("[attn]\nhidden = 3\n", "attn", "unknown table"),
        ("[sources\n", "TOML syntax", "line 1"),
    ],
)
def test_bad_settings_name_file_field_and_problem(
    tmp_path: Path, text: str, where: str, problem: str
) -> None:
    path = tmp_path / "transfer.toml"
    path.write_text(text)
    with pytest.raises(TransferConfigError, match=problem) as info:
        load_transfer_config(path)
    assert info.value.where == where and str(path) in str(info.value)


def test_a_partial_file_keeps_the_other_defaults(tmp_path: Path) -> None:
    path = tmp_path / "transfer.toml"
    path.write_text("[attention]\nprior_weight = 1\n[fusion]\nhidden = [64]\n")
    config = load_transfer_config(path)
    assert config.prior_weight == 1.0 and config.fusion_hidden == (64,)
    assert config.k == TransferConfig().k
    assert config.policy_kwargs()["fusion_hidden"] == [64]


def test_a_config_built_in_code_still_names_its_python_field() -> None:
    with pytest.raises(ValueError, match="pst_keep must be at least 1, got 0"):
        TransferConfig(pst_keep=0)
    with pytest.raises(ValueError, match="k must be at least 1, got 0"):
        TransferConfig(k=0)
    with pytest.raises(ValueError, match=r"prior_weight must be in \[0, 1\], got nan"):
        TransferConfig(prior_weight=float("nan"))


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        # Each was accepted: 2.5 sources, residual "1" and True as one source.
        ("k", 2.5, "k must be an integer, got float 2.5"),
        ("k", True, "k must be an integer, got bool True"),
        ("residual", 1, "residual must be a boolean, got int 1"),
        ("fusion_hidden", (64.0,), r"must be a list of integers, got tuple \(64\.0,\)"),
    ],
)
def test_a_config_built_in_code_refuses_a_value_of_another_kind(
    field: str, value: object, message: str
) -> None:
    with pytest.raises(TypeError, match=message):
        TransferConfig(**{field: value})


def test_a_config_built_in_code_takes_an_integer_for_a_number_and_a_list_for_widths() -> None:
    config = TransferConfig(min_success=1, fusion_hidden=[64, 32])
    assert config.min_success == 1 and config.fusion_hidden == (64, 32)
    # NumPy's numbers (a sweep over np.arange), kept as Python's so the record is JSON.
    import numpy as np

    config = TransferConfig(k=np.int64(2), prior_weight=np.float32(0.5), residual=np.bool_(False))
    assert type(config.k) is int and type(config.prior_weight) is float
    assert config.residual is False


@pytest.mark.parametrize(
    ("text", "where", "bound"),
    [
        # No upper bound: a network of terabytes, thousands of sources, thousands of paid calls.
        ("[attention]\nhidden = {}\n", "attention.hidden", 4096),
        ("[fusion]\nhidden = [64, {}]\n", "fusion.hidden", 4096),
        ("[sources]\nk = {}\n", "sources.k", 32),
        ("[pst]\nkeep = {}\n", "pst.keep", 32),
        ("[analyzer]\nretries = {}\n", "analyzer.retries", 10),
    ],
)
def test_widths_and_counts_have_an_upper_bound(
    tmp_path: Path, text: str, where: str, bound: int
) -> None:
    path = tmp_path / "transfer.toml"
    path.write_text(text.format(bound))
    load_transfer_config(path)  # the bound itself loads
    path.write_text(text.format(bound + 1))
    with pytest.raises(TransferConfigError) as info:
        load_transfer_config(path)
    assert (info.value.path, info.value.where) == (str(path), where)
    assert f"at most {bound:,}, got" in info.value.problem


def test_a_config_built_in_code_takes_the_upper_bounds() -> None:
    with pytest.raises(ValueError, match="attention_hidden must be at most 4,096, got 4097"):
        TransferConfig(attention_hidden=4097)
    with pytest.raises(ValueError, match="analyzer_retries must be at most 10, got 11"):
        TransferConfig(analyzer_retries=11)
