"""Data-parallel training: the sampler's shards, and a real two-process ``torchrun`` (gloo, CPU) run
of the trainer against a reference computed by hand in one process.

Why not "2 ranks × batch 1 = 1 process × batch 2": the two are different computations. Batch norm
normalises each rank's own volume (DDP has no cross-process batch norm on CPU, and the trainer
keeps per-process batch norm on CUDA too), while one process normalises the two volumes together;
and the semantic loss of one process averages cross-entropy over both volumes' voxels and Lovász
over their union, not the mean of two per-volume losses. What DDP computes is exactly: every rank
runs its own volume with its own batch statistics, the gradients are averaged (each halved, then
summed: exact in float32 for two ranks), one Adam step on every rank, rank 0's running statistics
kept. The reference below does that in one process, and the run must match it.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from dsnet_core.io.semantickitti import SemanticKittiReader
from dsnet_core.model.bundle import load_shift_weights
from dsnet_core.model.checkpoint import load_checkpoint
from dsnet_core.train.data import load_sample
from dsnet_core.train.distributed import Distributed, shard
from dsnet_core.train.loop import STAGES
from dsnet_core.train.shifting import clusterer_for, make_shift_module, shift_error, shift_samples
from tests.dsnet_core.train.test_loop import LM, one_thread, trainer  # noqa: F401
from tests.helpers.ddp_train import digest
from tests.helpers.tiny_log import write_tiny_log

REPO = Path(__file__).resolve().parents[3]


def torchrun(nproc: int, *args) -> list[str]:
    """The command line of a real ``torchrun --standalone`` (a free port on localhost)."""
    return [sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={nproc}"] + [
        str(a) for a in args
    ]


def env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"}


# -- the sampler ---------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 3, 5, 8, 13])
@pytest.mark.parametrize("world", [1, 2, 3, 4])
def test_shards_have_equal_lengths_and_cover_the_epoch_padded_by_repetition(n, world):
    order = np.random.default_rng([7, 0, 3]).permutation(n)
    shards = [shard(order, world, r) for r in range(world)]
    length = -(-n // world)
    assert all(len(s) == length for s in shards)  # every rank takes the same number of steps
    dealt = np.stack(shards, 1).reshape(-1)  # position-major: the padded order itself
    total = length * world
    assert np.array_equal(dealt, np.resize(order, total))
    assert np.array_equal(dealt[:n], order)  # the epoch once, in its order ...
    assert np.array_equal(dealt[n:], np.resize(order, total - n))  # ... then repeats from its start
    if n % world == 0:  # nothing padded: the shards are disjoint and partition the epoch
        assert len(set(dealt.tolist())) == n
    assert set(dealt.tolist()) == set(range(n))


def test_shards_are_disjoint_before_the_padding_and_deterministic_per_seed_and_epoch():
    def epoch(seed, e, world=4, n=10):
        order = np.random.default_rng([seed, STAGES.index("semantic"), e]).permutation(n)
        return [shard(order, world, r) for r in range(world)]

    shards = epoch(0, 1)
    seen = [int(i) for s in shards for i in s[:2]]  # positions 0..7 of the order: no padding yet
    assert len(seen) == len(set(seen)) == 8
    assert all(np.array_equal(a, b) for a, b in zip(shards, epoch(0, 1), strict=True))
    assert any(not np.array_equal(a, b) for a, b in zip(shards, epoch(0, 2), strict=True))
    assert any(not np.array_equal(a, b) for a, b in zip(shards, epoch(1, 1), strict=True))


def test_a_global_step_takes_the_volumes_one_process_with_the_whole_batch_would():
    order = np.arange(100, 112)  # 12 volumes, 3 ranks × batch 2 = one process's batch 6
    world, b = 3, 2
    shards = [shard(order, world, r) for r in range(world)]
    for step in range(2):
        taken = sorted(int(i) for s in shards for i in s[step * b : (step + 1) * b])
        assert taken == sorted(order[step * b * world : (step + 1) * b * world].tolist())


def test_validation_parts_are_contiguous_and_in_order():
    for n in range(0, 9):
        for world in (1, 2, 3, 5):
            parts = [Distributed(rank=r, world_size=world).part(n) for r in range(world)]
            assert [i for p in parts for i in p] == list(range(n))
            assert max(len(p) for p in parts) - min(len(p) for p in parts) <= 1


def test_one_process_is_its_own_world():
    one = Distributed()
    assert not one.active and one.is_main
    assert one.from_main(lambda: 3) == 3 and one.all_gather([1.5]) == [[1.5]]
    model = torch.nn.Linear(2, 2)
    assert one.wrap(model, torch.device("cpu")) is model


# -- two gloo processes ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ddp_run(tmp_path_factory):
    """One real ``torchrun`` of two CPU processes: all stages, one epoch each, on 3 frames (an odd
    count: the epoch is padded with the first volume of the order)."""
    root = tmp_path_factory.mktemp("ddp")
    log = write_tiny_log(root / "log", frames=3)
    ckpt, report = root / "ckpt", root / "report"
    report.mkdir()
    epochs = {"semantic": 1, "offset": 1, "shift": 1}
    cmd = torchrun(2, "-m", "tests.helpers.ddp_train", log, ckpt, report, json.dumps(epochs))
    res = subprocess.run(cmd, cwd=REPO, env=env(), capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    ranks = [json.loads((report / f"rank{r}.json").read_text()) for r in (0, 1)]
    return log, ckpt, report, ranks


def test_every_rank_holds_the_same_weights_after_every_step(ddp_run):
    _, _, _, (r0, r1) = ddp_run
    assert [s[:3] for s in r0["steps"]] == [[st, 1, k] for st in ("semantic", "offset") for k in (1, 2)]
    assert r0["steps"] == r1["steps"]  # sha256 of the parameters, step by step
    assert r0["final"] == r1["final"]  # parameters and (synchronised) batch-norm statistics


def test_only_rank_0_writes_the_checkpoint(ddp_run):
    _, ckpt, _, (r0, r1) = ddp_run
    assert r1["writes"] == []
    assert any(w.endswith("model.safetensors") for w in r0["writes"])  # the hook does see writes
    files = sorted(p.name for p in ckpt.iterdir())
    assert files == [
        "card.json",
        "metrics.csv",
        "metrics.json",
        "model.safetensors",
        "shift.safetensors",
        "train_state.json",
        "train_state.safetensors",
    ]
    card = json.loads((ckpt / "card.json").read_text())
    assert card["training_data"]["train_config"]["world_size"] == 2
    assert card["epochs"] == {"semantic": 1, "offset": 1, "shift": 1}
    assert len((ckpt / "metrics.csv").read_text().splitlines()) == 4


def test_two_ranks_equal_the_reference_computed_by_hand(ddp_run, tmp_path):
    """The semantic epoch of the two-rank run against the same epoch done by hand in one process:
    per step, each rank's volume through the network with its own batch statistics, the mean of the
    two gradients, one Adam step, rank 0's running statistics kept. Tolerance: bit-identical (the
    same float32 operations in the same order on one thread; halving and adding two gradients is
    exact, whatever order gloo adds them in)."""
    log, _, report, _ = ddp_run
    t = trainer(log, tmp_path / "ref", stage="semantic", epochs={"semantic": 1})  # same seed: same start
    reader = SemanticKittiReader(log)
    opt = t.optimizer("semantic")
    for group in opt.param_groups:
        group["lr"] = t.epoch_lr("semantic", 0, 1)
    rng = np.random.default_rng([t.cfg.seed, STAGES.index("semantic"), 0])
    rng.integers(2**31)  # the epoch's torch seed (nothing random in the forward pass)
    order = rng.permutation(len(t.train_vols))
    shards = [shard(order, 2, r) for r in (0, 1)]
    assert sorted(shards[0].tolist() + shards[1].tolist()) == sorted([*order.tolist(), order[0]])
    t.train_modes("semantic")
    params = [p for p in t.model.parameters() if p.requires_grad]
    for step in range(len(shards[0])):
        grads = {}
        for r in (1, 0):  # rank 1 first: its running statistics are dropped (DDP broadcasts rank 0's)
            kept = {k: b.clone() for k, b in t.model.named_buffers()}
            opt.zero_grad(set_to_none=True)
            sample = load_sample(reader, t.train_vols[shards[r][step]], LM)
            t.loss("semantic", [sample], t.model, rng).backward()
            grads[r] = [p.grad.clone() for p in params]
            if r == 1:
                for k, b in t.model.named_buffers():
                    b.copy_(kept[k])
        for p, g0, g1 in zip(params, grads[0], grads[1], strict=True):
            p.grad = g0 * 0.5 + g1 * 0.5
        opt.step()
    ddp = load_file(str(report / "rank0_semantic1.safetensors"))
    ref = t.model.state_dict()
    assert ddp.keys() == ref.keys()
    worst = max(float((ddp[k].double() - ref[k].double()).abs().max()) for k in ref)
    assert worst == 0.0, f"largest difference {worst}"
    # and the hand reference is not what a single process with batch 2 computes (batch norm, losses)
    one = trainer(log, tmp_path / "batch2", stage="semantic", epochs={"semantic": 1}, batch_size=2)
    one.run()
    assert any(not torch.equal(one.model.state_dict()[k], ref[k]) for k in ref)


def test_validation_gathered_from_two_ranks_equals_one_process(ddp_run):
    """The card's numbers (each rank validated its part) equal one process validating the saved
    weights: mIoU and per-class IoU from summed confusion counts, offset and shift errors summed
    in volume order."""
    log, ckpt, _, _ = ddp_run
    card = json.loads((ckpt / "card.json").read_text())
    offset, shift = card["metrics"][1], card["metrics"][2]
    epochs = {"semantic": 1, "offset": 1, "shift": 1}
    t = trainer(log, ckpt, resume=True, stage="all", epochs=epochs)  # loads the weights, writes nothing
    val = t.validate()
    assert (val["val_miou"], val["val_offset_l1"], val["val_iou"]) == (
        offset["val_miou"],
        offset["val_offset_l1"],
        offset["val_iou"],
    )
    module = make_shift_module(1, t.model.config.ins_dim)
    module.load_state_dict(load_shift_weights(ckpt))
    seeds = shift_samples(t.model, t.val_reader, t.val_vols, LM, clusterer_for(1).n_seeds, t.device)
    assert shift_error(module, seeds, t.device) == shift["val_shift_l1"]


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_early_stopping_restores_the_same_best_weights_on_every_rank(tmp_path):
    """Rank 0 keeps the best weights in a file that every rank reads back when a stage stops: the
    ranks end identical, with the checkpoint's weights, and the file is gone."""
    log = write_tiny_log(tmp_path / "log", frames=5)
    ckpt, report = tmp_path / "ckpt", tmp_path / "report"
    report.mkdir()
    epochs = json.dumps({"semantic": 3, "offset": 2, "shift": 0})
    extra = json.dumps({"patience": 1, "holdout": 0.4, "lr": 0.05})
    cmd = torchrun(2, "-m", "tests.helpers.ddp_train", log, ckpt, report, epochs, extra)
    res = subprocess.run(cmd, cwd=REPO, env=env(), capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    r0, r1 = (json.loads((report / f"rank{r}.json").read_text()) for r in (0, 1))
    card = json.loads((ckpt / "card.json").read_text())
    stops = card["training_data"]["early_stop"]
    assert set(stops) == {"semantic", "offset"}
    # the offset stage trains on the kept semantic weights (backbone frozen): its mIoU is theirs
    assert all(m["val_miou"] == stops["semantic"]["value"] for m in card["metrics"] if m["stage"] == "offset")
    assert r1["writes"] == [] and r0["steps"] == r1["steps"] and r0["final"] == r1["final"]
    model, _ = load_checkpoint(ckpt)
    assert digest(model.state_dict()) == r0["final"]
    assert not list(ckpt.glob("best_*"))
