"""The shipped library is registered in a new skill space once, and never forced back."""

from __future__ import annotations

import numpy as np

from itskill.rl import load_policy
from itskill.sim.layout import OBSERVATION_LAYOUT
from itskill.skills import ManifestEntry, open_skill_space, read_manifest, write_manifest
from itskill.skills.library import SHIPPED_LIBRARY as SHIPPED


def test_fresh_skill_space_gets_the_shipped_library_once(tmp_path, monkeypatch, home) -> None:
    shipped = tmp_path / "shipped"
    entries = []
    for task in ("reach_nut_m12", "pick_nut_m12"):
        (shipped / task).mkdir(parents=True)
        (shipped / task / "policy.safetensors").write_bytes(b"weights")
        entries.append(
            ManifestEntry(
                name=task,
                task=task,
                description=f"command of {task}",
                actions=("approach",),
                checkpoint=f"{task}/policy.safetensors",
                success=0.9,
                steps=1000,
            )
        )
    write_manifest(shipped, entries)
    monkeypatch.setattr("itskill.skills.library.SHIPPED_LIBRARY", shipped)

    with open_skill_space() as space:
        skills = {s.name: s for s in space.list()}
        assert sorted(skills) == ["pick_nut_m12", "reach_nut_m12"]
        assert skills["pick_nut_m12"].success_rate == 0.9
        space.remove("pick_nut_m12")
    # A user's removal sticks: the library is not installed a second time.
    with open_skill_space() as space:
        assert [s.name for s in space.list()] == ["reach_nut_m12"]


def test_every_shipped_skill_loads_and_acts() -> None:
    # A checkpoint whose saved policy description the current code cannot build (a field that
    # was since removed) would only fail when transfer picks it as a source.
    entries = read_manifest(SHIPPED)
    assert entries, "the package ships no skill library"
    obs = np.zeros((1, OBSERVATION_LAYOUT.size), dtype=np.float32)
    for entry in entries:
        policy = load_policy((SHIPPED / entry.checkpoint).parent)
        actions, _ = policy.predict(obs, deterministic=True)
        assert actions.shape == (1, 5), entry.name
        assert entry.success is not None and 0.0 <= entry.success <= 1.0, entry.name
