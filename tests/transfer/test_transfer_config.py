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
        ("[attention]\nprior_weight = 1.5\n", "values", r"prior_weight must be in \[0, 1\]"),
        ("[attention]\nhidden = 'wide'\n", "attention.hidden", "expected an integer"),
        ("[fusion]\nhidden = [64, 'x']\n", "fusion.hidden", "list of integers"),
        ("[sources]\ntop = 3\n", "sources.top", "unknown field; expected one of"),
        ("[pst]\nkeep = 0\n", "values", "pst_keep must be at least 1"),
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
