"""A new method through the public interface only: one class (its stages, settings, model grid,
bundled checkpoints, trainer options and trainer), one ``register`` call; then it labels a log
through the real flow (``dsnet label``'s request, a Prefect server) and trains for one step through
its generated ``dsnet train`` command. Nothing else in the product is touched."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
import typer
from pydantic import Field
from typer.testing import CliRunner

from dsnet_core.model.checkpoint import ModelCard, save_tensors
from dsnet_core.train.skeleton import EpochPlan, TrainerSkeleton, prepare_out
from tasks.ingest import IngestStage
from tasks.methods import METHODS, LabelSettings, Method, TrainOptions, get_method, register
from tasks.pipeline import Pipeline
from tests.tasks.test_toy_stage import RangeStage


class ToyTrainOptions(TrainOptions):
    """Fit the range scale of a toy model (one parameter) to the log's mean range."""

    epochs: str = Field("1", description="Epochs (one step each).")


class ToyTrainer(TrainerSkeleton):
    stage_names = ("fit",)
    metric_columns = ("stage", "epoch", "train_loss", "val_mean_range")

    def __init__(self, options: ToyTrainOptions, ranges: np.ndarray) -> None:
        self.out, self.options, self.device = Path(options.out), options, torch.device("cpu")
        self.target = torch.tensor(float(ranges.mean()))
        torch.manual_seed(options.seed)
        self.model = torch.nn.Linear(1, 1, bias=False)
        prepare_out(self.out, options.resume)
        self.card = ModelCard(architecture={"toy": 1}, class_map={}, training_data={}, epochs={}, metrics=[])

    def epochs_of(self, stage: str) -> int:
        return int(self.options.epochs)

    def epoch_lr(self, stage: str, epoch: int, total: int) -> float:
        return self.options.lr

    def optimizer(self, stage: str) -> torch.optim.Optimizer:
        return torch.optim.SGD(self.model.parameters(), lr=self.options.lr)

    def epoch_plan(self, stage: str, epoch: int) -> EpochPlan:  # one sample: one step an epoch
        return self.shuffled_plan([self.options.seed, epoch], 1, lambda i, rng: i)

    def loss(self, stage, batch, net, rng) -> torch.Tensor:
        return (net(torch.ones(1, 1)).squeeze() - self.target) ** 2

    def validate(self, stage: str) -> dict[str, Any]:
        return {"val_mean_range": float(self.model.weight.detach())}

    def write_checkpoint(self, staging: Path, stage: str, extra: dict) -> None:
        save_tensors(self.model.state_dict(), staging / "model.safetensors")
        (staging / "card.json").write_text(json.dumps(self.card.__dict__))


class Toy(Method):
    name = "toy"
    title = "a toy method (ranges, everything road)"
    default_scans = 1
    TrainOptions = ToyTrainOptions

    def pipeline(
        self, options: Mapping[str, Any] | None = None, stages: Mapping[str, Mapping[str, Any]] | None = None
    ) -> Pipeline:
        return Pipeline(self.name, (IngestStage(), RangeStage()), labels="toy_range")

    def stage_configs(self, settings: LabelSettings) -> dict[str, dict[str, Any]]:
        return {"toy_range": {"scale": 2.0}}

    def model_grid(self, stages) -> None:
        return None

    def bundled_checkpoint(self, scans: int) -> None:
        return None

    def train(self, options: TrainOptions, on_step=None) -> str:
        from dsnet_core.io.formats import open_log

        reader = open_log(options.data)
        seq = reader.sequences()[0]
        ranges = np.concatenate([np.linalg.norm(reader.scan(f)[:, :3], axis=1) for f in reader.frames(seq)])
        card = ToyTrainer(options, ranges).run(on_step)
        return f"wrote toy checkpoint {options.out} (epochs {card.epochs})"


@pytest.fixture
def toy():
    method = register(Toy())
    yield method
    METHODS.pop(method.name)


def test_a_toy_method_labels_a_log_and_trains_one_step(toy, prefect_api_url, synth_log, tmp_path):
    from flows.commands.train import method_command
    from flows.export import export_semantickitti
    from flows.label import label_dataset
    from flows.request import LabelRequest
    from storage.run import RunStore

    assert get_method("toy") is toy
    with pytest.raises(ValueError, match="--tta: not a setting of method toy"):
        LabelRequest.from_settings(LabelSettings(tta=4), data=str(synth_log), root="r", method="toy")
    request = LabelRequest.from_settings(
        LabelSettings(), data=str(synth_log), root=str(tmp_path / "run"), method="toy", sequences=["00"]
    )
    summary = label_dataset(request)
    assert [r["stage"] for r in summary] == ["ingest", "toy_range"]
    store = RunStore(tmp_path / "run")
    assert store.read_manifest("00", "toy_range").config == {"scale": 2.0}
    out = export_semantickitti(str(tmp_path / "run"), tmp_path / "pred")
    assert out.frames == {"00": 6}

    app = typer.Typer()
    app.command(name="toy")(method_command(toy))
    res = CliRunner().invoke(app, [str(synth_log), "--out", str(tmp_path / "ckpt"), "--lr", "0.1"])
    assert res.exit_code == 0, res.output
    assert "wrote toy checkpoint" in res.output
    card = json.loads((tmp_path / "ckpt" / "card.json").read_text())
    assert card["epochs"] == {"fit": 1} and card["metrics"][0]["stage"] == "fit"
    assert (tmp_path / "ckpt" / "metrics.csv").read_text().splitlines()[0] == (
        "stage,epoch,train_loss,val_mean_range"
    )
    again = CliRunner().invoke(app, [str(synth_log), "--out", str(tmp_path / "ckpt")])
    assert again.exit_code == 2 and "already holds a checkpoint: pass --resume" in again.output
