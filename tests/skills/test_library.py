"""The shipped library is registered in a new skill space once, and never forced back."""

from __future__ import annotations

from itskill.skills import ManifestEntry, open_skill_space, write_manifest


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
