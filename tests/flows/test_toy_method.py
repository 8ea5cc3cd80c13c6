"""A new method through the public interface only: one class (its stages, settings, model grid,
bundled checkpoints, trainer options and trainer), one ``register`` call; then it labels a log
through the real flow (``dsnet label``'s request, a Prefect server) and trains for one step through
its generated ``dsnet train`` command. Nothing else in the product is touched."""

from __future__ import annotations

import json
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
import torch
import typer
from pydantic import Field
from typer.testing import CliRunner

from dsnet_core.labels import class_map_of, load_label_map
from dsnet_core.model.card import card_text
from dsnet_core.model.checkpoint import ModelCard, save_tensors
from dsnet_core.train.skeleton import EpochPlan, TrainerSkeleton, prepare_out
from storage.contract import ArraySpec, TableSpec
from tasks.base import CLASS_MAP, FRAME_LABEL, ItemResult, Plan, Stage, StageContext
from tasks.confidence import PROBS
from tasks.ingest import IngestStage
from tasks.methods import METHODS, LabelSettings, Method, TrainOptions, get_method, register
from tasks.pipeline import Pipeline
from tests.tasks.test_toy_stage import RangeStage

LM = load_label_map("semantic-kitti")
CAR, ROAD = (int(LM.to_train(np.asarray([raw]))[0]) for raw in (10, 40))
OBJECTS = TableSpec(
    "toy_objects",
    pa.schema([("index", pa.int32()), ("id", pa.int32()), ("class_id", pa.int32()), ("n_points", pa.int64()),
               ("confidence", pa.float64())]),
    roles=(("item", "index"), ("id", "id"), ("class_id", "class_id"), ("points", "n_points"),
           ("confidence", "confidence")),
)  # fmt: skip


class ObjectStage(Stage):
    """The toy's labels: the nearer half of each frame's points one car (confidence 0.3 + 0.1 ×
    frame), the rest road; class probabilities 0.6 (car) and 0.9 (road). It declares what the report
    reads for frame confidence and the review queue: infer's probabilities, ``sem``, ``inst`` and a
    table with the ``item``, ``id`` and ``confidence`` roles."""

    name = "toy_objects"
    upstream = ("toy_range",)
    version = "1"
    item = "frame"
    arrays = (FRAME_LABEL, PROBS, ArraySpec("sem", "uint8"), ArraySpec("inst", "int32"))
    tables = (OBJECTS,)

    def plan(self, ctx: StageContext) -> Plan:
        n = ctx.frames["n_points"].to_pylist()
        return Plan(len(n), max(n), meta={CLASS_MAP: class_map_of(LM)}, dims={"classes": LM.num_classes})

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        ranges = ctx.arrays("toy_range")
        for i in items:
            r = ranges.read_item(i, ["range"])["range"]
            near = r < np.median(r)
            sem = np.where(near, CAR, ROAD).astype(np.uint8)
            inst = near.astype(np.int32)
            probs = np.zeros((r.size, LM.num_classes), np.uint8)
            probs[np.arange(r.size), sem] = np.where(near, 153, 230)  # 0.6, 0.9
            label = LM.to_raw(sem).astype(np.uint32) | (inst.astype(np.uint32) << 16)
            row = {
                "index": i,
                "id": 1,
                "class_id": CAR,
                "n_points": int(near.sum()),
                "confidence": 0.3 + 0.1 * i,
            }
            yield ItemResult(
                i,
                arrays={"label": label, "probs": probs, "sem": sem, "inst": inst},
                n_points=r.size,
                rows={"toy_objects": [row]},
                counts={"frames": 1, "points": int(r.size)},
            )


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
        (staging / "card.json").write_text(card_text(self.card.__dict__))


class Toy(Method):
    name = "toy"
    title = "a toy method (ranges, everything road)"
    default_scans = 1
    TrainOptions = ToyTrainOptions

    def pipeline(
        self, options: Mapping[str, Any] | None = None, stages: Mapping[str, Mapping[str, Any]] | None = None
    ) -> Pipeline:
        return Pipeline(self.name, (IngestStage(), RangeStage(), ObjectStage()), labels="toy_objects")

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
    assert [r["stage"] for r in summary] == ["ingest", "toy_range", "toy_objects"]
    store = RunStore(tmp_path / "run")
    assert store.read_manifest("00", "toy_range").config == {"scale": 2.0}
    out = export_semantickitti(str(tmp_path / "run"), tmp_path / "pred")
    assert out.frames == {"00": 6}
    _confidence_and_review_queue(store)

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


def _confidence_and_review_queue(store) -> None:
    """The report's frame confidence and review queue, and the dashboard's sections, of a method
    none of whose stages is DS-Net's: read from what its labels stage declares."""
    from flows.report.tables import REPORT_TABLES
    from storage.run import DASHBOARD

    rows = {r["index"]: r for r in store.read_all(REPORT_TABLES["frame_confidence"]).to_pylist()}
    assert sorted(rows) == list(range(6))
    for i, r in rows.items():
        near = int(store.arrays("00", ObjectStage().contract).read_item(i, ["inst"])["inst"].sum())
        n = r["n_points"]
        assert r["semantic"] == pytest.approx(((n - near) * 230 + near * 153) / 255 / n, rel=1e-6)
        assert r["agreement"] == pytest.approx(0.3 + 0.1 * i) and r["stitch"] == 1.0
        assert r["n_instances"] == 1
    queue = store.read_all(REPORT_TABLES["review_queue"]).to_pylist()
    assert [(q["source"], q["item"], q["class"]) for q in queue] == [
        ("toy_objects/toy_objects", i, "car") for i in range(6)
    ]
    page = Path(store.root.path(DASHBOARD)).read_text()
    assert 'id="s-confidence"' in page and "confidence per frame" in page
    assert 'id="s-review"' in page and "<td>toy_objects</td>" in page  # the stage, not its table
