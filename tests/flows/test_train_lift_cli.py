"""``dsnet train dsnet --init-from PLAIN --equivariant n``: a plain model lifted to C_n and fine-tuned."""

from __future__ import annotations

import json

import torch
from typer.testing import CliRunner

from flows.cli import app
from tests.helpers.tiny_log import write_tiny_log
from tests.model_helpers import make_checkpoint


def test_init_from_a_plain_model_with_equivariant_lifts_it(tmp_path):
    before = torch.get_num_threads()
    log = write_tiny_log(tmp_path / "log", frames=2)
    plain = make_checkpoint(tmp_path / "plain")
    args = [
        "train",
        "dsnet",
        str(log),
        "--out",
        str(tmp_path / "eq4"),
        "--init-from",
        str(plain),
        "--equivariant",
        "4",
    ]
    res = CliRunner().invoke(app, [*args, "--epochs", "semantic=0,offset=1,shift=0", "--no-augment"])
    torch.set_num_threads(before)
    assert res.exit_code == 0, res.output
    card = json.loads((tmp_path / "eq4" / "card.json").read_text())
    assert card["architecture"]["equivariant"] == 4 and card["epochs"] == {"offset": 1}
    assert card["training_data"]["init_from"]["path"] == str(plain.resolve())
