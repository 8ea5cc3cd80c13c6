"""Shifting + clustering + fusion on oracle inputs (no network): ground-truth semantics and box
centres plus regression noise and oracle features, on the synthetic log of the ``synth_log``
fixture, scored by the project's evaluator. The shifting weights were trained on a log of another
seed by ``bench/ablation_clustering.py oracle --save-weights
tests/dsnet_core/oracle/data/shift_oracle.safetensors``."""

from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from dsnet_core.instance.clustering import DynamicShiftConfig, get_clusterer
from dsnet_core.instance.fusion import fuse
from dsnet_core.instance.shifting import DynamicShift
from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.labels import load_label_map
from dsnet_core.metrics import PanopticEvaluator
from dsnet_core.oracle.inputs import oracle_inputs
from dsnet_core.train.shifting import make_sample, train_shift

torch.set_num_threads(1)  # the machines behave like one core; extra threads only spin

WEIGHTS = Path(__file__).parent / "data" / "shift_oracle.safetensors"
LABEL_MAP = load_label_map("semantic-kitti")


def _frames(root: Path, every: int = 1):
    reader = SemanticKittiReader(root)
    for seq in reader.sequences():
        for frame in reader.frames(seq)[::every]:
            pts = reader.scan(frame)
            lab = reader.labels(frame, len(pts))
            yield (
                np.ascontiguousarray(pts[:, :3]),
                LABEL_MAP.to_train(lab & 0xFFFF),
                (lab >> 16).astype(np.int64),
            )


@pytest.fixture(scope="module")
def oracle_frames(synth_log):
    out = []
    for i, (xyz, sem, inst) in enumerate(_frames(synth_log, every=2)):
        out.append((xyz, sem, inst, oracle_inputs(xyz, sem, inst, LABEL_MAP.things, noise_seed=i)))
    return out


def test_oracle_pipeline_recovers_instances(oracle_frames):
    clusterer = get_clusterer(DynamicShiftConfig(), load_file(WEIGHTS))
    ev = PanopticEvaluator(LABEL_MAP, keep_rows=False)
    for xyz, sem, inst, o in oracle_frames:
        ids = clusterer.cluster(xyz[o.thing], o.centres, o.features.astype(np.float16))
        raw = np.zeros(len(xyz), np.int64)
        raw[o.thing] = ids
        fused = fuse(xyz, sem, raw, LABEL_MAP.things)
        ev.add_train(sem, inst, fused.semantic, fused.instance)
        # fusion: stuff untouched, one class per instance
        assert (fused.instance[~o.thing] == 0).all() and (fused.semantic[~o.thing] == sem[~o.thing]).all()
        for i in fused.instances.id:
            assert np.unique(fused.semantic[fused.instance == i]).size == 1
    res = ev.result().panoptic
    assert res.pq_things >= 0.9, {k: round(v.pq, 3) for k, v in res.per_class.items() if v.thing}


def test_training_lowers_the_shift_loss_and_moves_seeds_to_centres(oracle_frames):
    torch.manual_seed(0)
    xyz, _, _, o = oracle_frames[0]
    sample = make_sample(xyz[o.thing], o.centres, o.features, o.gt_centres, 1500)
    module = DynamicShift()
    losses = train_shift(module, [sample], steps=40, lr=3e-3)
    assert np.mean(losses[-5:]) < 0.8 * np.mean(losses[:5])
    with torch.no_grad():
        out = module(torch.from_numpy(sample.centres), torch.from_numpy(sample.features))
    before = np.abs(sample.centres - sample.gt).sum(axis=1).mean()
    after = (out.positions[-1] - torch.from_numpy(sample.gt)).abs().sum(dim=1).mean().item()
    assert after < before
