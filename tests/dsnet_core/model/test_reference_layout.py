"""The importer against the reference networks' state dicts as their own code registers them.

``fixtures/reference_state_dicts.json`` was recorded by instantiating the reference classes on CPU
(how: ``fixtures/README.md``): hongfz16/DS-Net at commit 4a73e2fe529798ad4ec3256d89411f59d2c10416
(``dsnet``, ``dsnet4d``, ``dsnet_offset``) and xinge008/Cylinder3D at commit
30a0abb2ca4c657a821a5e9a343934b0789b2365 (``cylinder3d``). Files built here hold random tensors of
exactly the recorded keys, shapes and dtypes at the released width (INIT_SIZE / init_size 32).
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest
import torch

from dsnet_core.model.bundle import load_shift_weights
from dsnet_core.model.checkpoint import load_checkpoint
from dsnet_core.model.importer import import_checkpoint
from dsnet_core.model.presets import CYLINDER3D, REFERENCE
from dsnet_core.model.reference_convert import convert_state
from dsnet_core.model.reference_names import training_buffers
from tests.dsnet_core.model.recorded import COMMITS, NETWORKS, random_state, rows, save_wrapped

#: recorded network → (kind it imports as, naming scheme, preset it must give)
IMPORTS = {
    "dsnet": ("dsnet", "dsnet", REFERENCE),
    "dsnet4d": ("dsnet4d", "dsnet", REFERENCE),
    "dsnet_offset": ("dsnet", "dsnet", REFERENCE),
    "cylinder3d": ("cylinder3d", "cylinder3d", CYLINDER3D),
}
SEEDS = {"dsnet": 0, "dsnet4d": 1}
SEM_LOSS = {
    "key": "sem_loss.weight",
    "shape": [20],
    "about": "class weights of the semantic loss (CrossEntropyLoss), used in training only",
}


def test_the_record_names_its_sources():
    assert {n: (v["repository"], v["commit"]) for n, v in NETWORKS.items()} == {
        "dsnet": ("hongfz16/DS-Net", COMMITS["hongfz16/DS-Net"]),
        "dsnet4d": ("hongfz16/DS-Net", COMMITS["hongfz16/DS-Net"]),
        "dsnet_offset": ("hongfz16/DS-Net", COMMITS["hongfz16/DS-Net"]),
        "cylinder3d": ("xinge008/Cylinder3D", COMMITS["xinge008/Cylinder3D"]),
    }
    assert [len(rows(n)) for n in NETWORKS] == [338, 338, 302, 274]


@pytest.mark.parametrize("name", list(IMPORTS))
def test_training_only_buffers_are_what_the_reference_registers_beyond_its_network(name):
    """Buffers that are neither parameters nor BatchNorm statistics: exactly the importer's list."""
    recorded = {
        key: (tuple(shape), owner)
        for key, shape, _, kind, owner in rows(name)
        if kind == "buffer" and not owner.startswith("BatchNorm")
    }
    _, scheme, _ = IMPORTS[name]
    known = training_buffers(scheme, 20)
    assert {k: s for k, (s, _) in recorded.items()} == {k: s for k, (s, _) in known.items()}
    assert set(recorded.values()) <= {((20,), "CrossEntropyLoss")}
    assert bool(recorded) == (scheme == "dsnet")


@pytest.mark.parametrize("name", list(IMPORTS))
def test_every_recorded_key_is_taken_or_dropped(name):
    """The recorded state dict (meta tensors) converts without an unknown, missing or mis-shaped key."""
    kind, scheme, preset = IMPORTS[name]
    state = {key: torch.empty(shape, device="meta") for key, shape, *_ in rows(name)}
    config, _, shift, summary = convert_state(state, kind, Path(f"{name}.pth"))
    assert config == preset
    assert summary["sparse_layout"] == "spconv1" and summary["rulebooks"] == "spconv1-shared"
    assert summary["dropped"]["training_buffers"] == ([SEM_LOSS] if scheme == "dsnet" else [])
    prefix = "backbone" if scheme == "dsnet" else "cylinder_3d_spconv_seg"
    assert summary["dropped"]["kernel_taps"] == [f"{prefix}.upBlock{i}.conv3.weight" for i in range(4)]
    assert len(shift) == (4 * 9 if name in ("dsnet", "dsnet4d") else 0)
    owners = Counter(owner for key, *_, owner in rows(name) if key.endswith(".weight"))
    assert summary["converted"] == {
        "sparse_convolutions": owners["SubMConv3d"] + owners["SparseConv3d"] + owners["SparseInverseConv3d"],
        "batch_norms": owners["BatchNorm1d"],
        "linear_layers": owners["Linear"],
        "shifting_iterations": 4 if name in ("dsnet", "dsnet4d") else 0,
    }
    assert sum(owners.values()) == sum(list(summary["converted"].values())[:3]) + len(
        summary["dropped"]["training_buffers"]
    )


@pytest.fixture(scope="module")
def full_width_files(tmp_path_factory):
    """The DS-Net and 4D-DS-Net records as files in the reference's checkpoint dict (~230 MB each)."""
    folder = tmp_path_factory.mktemp("full")
    return {
        name: save_wrapped(random_state(name, seed=SEEDS[name]), folder / f"{name}.pth")
        for name in ("dsnet", "dsnet4d")
    }


@pytest.mark.parametrize("name", ["dsnet", "dsnet4d"])
def test_a_file_in_the_recorded_layout_imports_at_the_released_width(full_width_files, tmp_path, name):
    src = full_width_files[name]
    card = import_checkpoint(src, tmp_path / "ckpt", name)
    imported = card.training_data["imported"]
    assert imported["kind"] == name and imported["width"] == 32 and card.architecture["width"] == 32
    assert imported["top_level_keys"] == NETWORKS[name]["top_level_keys"]
    assert imported["sparse_layout"] == "spconv1" and imported["grid_convention"] == "reference"
    assert imported["dropped"]["training_buffers"] == [SEM_LOSS]
    assert imported["bandwidths"] == ([0.2, 1.7, 3.2] if name == "dsnet" else [0.2, 1.8, 3.4])
    source = random_state(name, seed=SEEDS[name])  # what the file holds
    model, _ = load_checkpoint(tmp_path / "ckpt")
    ours = model.state_dict()
    assert torch.equal(
        ours["backbone.context.a1.bn.running_var"], source["backbone.downCntx.bn0.running_var"]
    )
    assert torch.equal(ours["point_encoder.compress.0.weight"], source["fea_compression.0.weight"])
    logits = source["sem_head.logits.weight"]  # spconv 1.x (3, 3, 3, 128, 20) → taps (27, 128, 20)
    assert torch.equal(ours["sem_head.conv.weight"], logits.reshape(27, 128, 20))
    shift = load_shift_weights(tmp_path / "ckpt")
    ref = "pytorch_meanshift.learnable_bandwidth_weights_layer_list.3"
    assert torch.equal(shift["mlps.3.3.weight"], source[f"{ref}.3.weight"])
    assert torch.equal(shift["mlps.3.1.running_mean"], source[f"{ref}.1.running_mean"])
