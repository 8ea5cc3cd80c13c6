"""Pipelines with the refine stage appended, built in the tests (methods are assembled elsewhere):
the oracle labels stage (perturbed ground truth) -> refine -> score, the same without refine, and
one with ground-truth probabilities per align volume (k = 2) as a model stage would store them."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from tasks.align import AlignStage
from tasks.base import ItemResult, Plan, Stage, StageContext
from tasks.ingest import IngestStage
from tasks.pipeline import Pipeline
from tasks.refine import PROBS, RefineStage
from tasks.score import ScoreStage
from tests.tasks.oracle_stitch import LM, OracleStitch

ORACLE_REFINE = Pipeline(
    "oracle-refine",
    (IngestStage(), OracleStitch(), RefineStage(labels="oracle"), ScoreStage(labels="refine")),
    labels="refine",
)
ORACLE_PLAIN = Pipeline(
    "oracle", (IngestStage(), OracleStitch(), ScoreStage(labels="oracle")), labels="oracle"
)


class OracleProbs(Stage):
    """Per volume of ``align``: class probabilities of the ground truth (0.6 on its class, the rest
    spread evenly), declared as infer declares them, so refine reads them as a model's."""

    name = "oracle_probs"
    upstream = ("align",)
    version = "1"
    item = "volume"
    arrays = (PROBS,)

    def plan(self, ctx: StageContext) -> Plan:
        align = ctx.manifest("align")
        return Plan(
            n_items=align.n_items, max_points=int(align.plan["max_points"]), dims={"classes": LM.num_classes}
        )

    def run_block(self, ctx: StageContext, items: list[int]) -> Iterator[ItemResult]:
        align = ctx.arrays("align")
        for v in items:
            sem = LM.lut(1 << 16, fill=0)[align.read_item(v, ["labels"])["labels"] & 0xFFFF]
            p = np.full((sem.size, LM.num_classes), 0.4 / (LM.num_classes - 2))
            p[:, 0] = 0
            p[np.arange(sem.size), np.maximum(sem, 1)] = 0.6
            yield ItemResult(v, arrays={"probs": np.rint(p * 255).astype(np.uint8)}, n_points=int(sem.size))


def _oracle_after_probs() -> OracleStitch:
    stage = OracleStitch()
    stage.upstream = ("ingest", "oracle_probs")  # its labels are made after the probabilities
    return stage


ORACLE_PROBS_REFINE = Pipeline(
    "oracle-probs-refine",
    (IngestStage(), AlignStage(), OracleProbs(), _oracle_after_probs(), RefineStage(labels="oracle")),
    labels="refine",
)
