"""An epoch's checkpoint files land together: every kill point inside a save recovers to one epoch."""

import pytest

from dsnet_core.train import commit


def _epoch(out, n: int, kill_after_moves: int | None = None, committed: bool = True) -> None:
    staging = commit.begin(out)
    for name in ("model.safetensors", "card.json", "train_state.json"):
        (staging / name).write_text(f"{name} epoch {n}")
    if not committed:
        return
    if kill_after_moves is None:
        commit.commit(out)
        return
    # commit by hand up to a kill: the marker, then only some of the moves
    import json
    import os

    names = sorted(p.name for p in staging.iterdir())
    (staging / commit.COMMIT).write_text(json.dumps(names))
    for name in names[:kill_after_moves]:
        os.replace(staging / name, out / name)


def _epochs(out) -> set[str]:
    return {(out / n).read_text().split()[-1] for n in ("model.safetensors", "card.json", "train_state.json")}


def test_committed_epoch_replaces_the_previous_one(tmp_path):
    _epoch(tmp_path, 1)
    _epoch(tmp_path, 2)
    assert _epochs(tmp_path) == {"2"} and not (tmp_path / commit.PENDING).exists()
    assert commit.recover(tmp_path) is None


def test_uncommitted_epoch_is_rolled_back(tmp_path):
    _epoch(tmp_path, 1)
    _epoch(tmp_path, 2, committed=False)
    assert commit.recover(tmp_path) == "rolled back"
    assert _epochs(tmp_path) == {"1"} and not (tmp_path / commit.PENDING).exists()


@pytest.mark.parametrize("moved", [0, 1, 2, 3])
def test_kill_during_the_moves_rolls_forward(tmp_path, moved):
    _epoch(tmp_path, 1)
    _epoch(tmp_path, 2, kill_after_moves=moved)
    assert commit.recover(tmp_path) == "rolled forward"
    assert _epochs(tmp_path) == {"2"} and not (tmp_path / commit.PENDING).exists()
