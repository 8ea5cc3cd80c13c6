"""A method's checkpoints are one description (:class:`dsnet_core.checkpoints.Checkpoints`) and the
card kinds one lookup: the bundled models per k, resolving, and another kind's card refused with the
method it belongs to."""

from __future__ import annotations

import json

import pytest

from dsnet_core.checkpoints import DPLS, DSNET, MOST, card_kind, checkpoint_digest, checkpoint_method
from dsnet_core.errors import CheckpointError
from dsnet_core.model.card import card_text
from tasks.methods import METHODS
from tests.model_helpers import make_checkpoint, make_most_checkpoint


def test_each_method_holds_its_description_and_bundled_models():
    assert {m: METHODS[m].checkpoints for m in ("dsnet", "most", "dpls")} == {
        "dsnet": DSNET, "most": MOST, "dpls": DPLS,
    }  # fmt: skip
    assert DSNET.bundled(1).name == "tiny-v2" and DSNET.bundled(3).name == "tiny-v2-4d"
    assert MOST.bundled(3).name == "most" and DPLS.bundled(2).name == "dpls"
    assert METHODS["most"].bundled_checkpoint(3) == MOST.bundled(3)
    assert DSNET.resolve(None, 2) == DSNET.bundled(2)


def test_another_kinds_card_is_refused_with_its_method(tmp_path):
    ds, most = make_checkpoint(tmp_path / "ds"), make_most_checkpoint(tmp_path / "most")
    assert (checkpoint_method(ds), checkpoint_method(most)) == ("dsnet", "most")
    assert DSNET.resolve(ds) == ds and MOST.resolve(most) == most
    with pytest.raises(
        CheckpointError, match=r"not a MOST checkpoint .* a DS-Net checkpoint: label with --method dsnet"
    ):
        MOST.resolve(ds)
    with pytest.raises(
        CheckpointError, match=r"not a DS-Net checkpoint .* a MOST checkpoint: label with --method most"
    ):
        DSNET.read_card(most)
    assert len({checkpoint_digest(ds), checkpoint_digest(most)}) == 2  # each read by its own kind
    card = json.loads((ds / "card.json").read_text())
    (ds / "card.json").write_text(card_text({**card, "format": "other/1"}))
    with pytest.raises(CheckpointError, match="unknown checkpoint format 'other/1'"):
        card_kind(ds)
