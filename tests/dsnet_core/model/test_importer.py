"""The checkpoint importer against a reconstruction of the reference networks in spconv 2.x.

The reconstruction (``reference_net.py``) registers what the reference networks register as
instantiated from their own code (``fixtures/reference_state_dicts.json``: hongfz16/DS-Net at
commit 4a73e2fe529798ad4ec3256d89411f59d2c10416, xinge008/Cylinder3D at commit
30a0abb2ca4c657a821a5e9a343934b0789b2365; see ``fixtures/README.md``), checked below at the
released width; its numbers are checked at a small width (4) of the same architecture. The
released files themselves cannot be fetched here. Full-width files: ``test_reference_layout.py``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from dsnet_core.errors import CheckpointImportError
from dsnet_core.model.bundle import load_shift_weights
from dsnet_core.model.checkpoint import load_checkpoint, sha256_file
from dsnet_core.model.cylinder import CylinderGrid, cylinder_features
from dsnet_core.model.importer import import_checkpoint
from tests.dsnet_core.model.recorded import NETWORKS, shapes
from tests.dsnet_core.model.reference_net import (
    Cylinder3DReference,
    DSNetReference,
    Run,
    randomize,
    reference_features,
    spconv1_state,
)


@pytest.fixture(autouse=True)
def one_thread():
    """spconv's CPU kernels give wrong results with more than one thread."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def scan(seed: int = 0, n: int = 2500) -> np.ndarray:
    """A street-like synthetic scan: ground, two walls, a few boxes; float32 (N, 4)."""
    rng = np.random.default_rng(seed)
    parts = [
        np.c_[rng.uniform(-40, 40, (n // 2, 2)), rng.normal(-1.7, 0.03, n // 2)],
        np.c_[rng.uniform(-40, 40, n // 5), np.full(n // 5, 8.0), rng.uniform(-1.7, 1.4, n // 5)],
        np.c_[rng.uniform(-40, 40, n // 5), np.full(n // 5, -7.5), rng.uniform(-1.7, 1.4, n // 5)],
    ]
    for cx, cy in ((10, 3), (-6, -2), (20, -4)):
        parts.append(
            np.c_[rng.uniform(cx - 2, cx + 2, 60), rng.uniform(cy - 1, cy + 1, 60), rng.uniform(-1.7, 0, 60)]
        )
    xyz = np.concatenate(parts)
    xyz = xyz[np.hypot(xyz[:, 0], xyz[:, 1]) > 2.0]  # a few fall inside ρ < 3 m and get clamped
    return np.c_[xyz, rng.uniform(0, 1, len(xyz))].astype(np.float32)


def shapes_in_spconv1(module: torch.nn.Module) -> dict[str, list[int]]:
    return {
        k: list(v.permute(1, 2, 3, 4, 0).shape if v.dim() == 5 else v.shape)
        for k, v in module.state_dict().items()
    }


@pytest.mark.parametrize(
    ("name", "make"),
    [
        ("dsnet", lambda: DSNetReference(32)),
        ("dsnet4d", lambda: DSNetReference(32)),
        ("dsnet_offset", lambda: DSNetReference(32, meanshift=False)),
        ("cylinder3d", lambda: Cylinder3DReference(32)),
    ],
)
def test_reconstruction_registers_what_the_reference_registers(name, make):
    """Every key and shape, parameters and buffers, of the reference as instantiated."""
    with torch.device("meta"):
        net = make()
    assert shapes_in_spconv1(net) == shapes(name)
    buffers = {k for k, _ in net.named_buffers()}
    assert buffers == {key for key, _, _, kind, _ in NETWORKS[name]["state_dict"] if kind == "buffer"}


def save_reference(net: torch.nn.Module, path: Path, layout: str, wrapped: bool) -> Path:
    state = net.state_dict() if layout == "spconv2" else spconv1_state(net.state_dict())
    obj = {
        "epoch": 7,
        "model_state": state,
        "optimizer_state": None,
        "other_state": {"best_pq": np.float64(0.5)},
    }
    torch.save(obj if wrapped else state, path)
    return path


def run_both(ref, ckpt: Path, points: np.ndarray, spconv1: bool):
    model, card = load_checkpoint(ckpt)
    model.eval()
    with torch.no_grad():
        want_logits, want_offsets = ref(points, model.config.grid, Run(spconv1))
        got = model([torch.from_numpy(points)], instance=want_offsets is not None)
    return (want_logits, want_offsets), got, card


@pytest.mark.parametrize("layout", ["spconv2", "spconv1"])
def test_dsnet_import_reproduces_the_reference(tmp_path, layout):
    ref = randomize(DSNetReference(4), seed=1)
    src = save_reference(ref, tmp_path / "dsnet.pth", layout, wrapped=True)
    card = import_checkpoint(src, tmp_path / "ckpt", "dsnet")
    imported = card.training_data["imported"]
    assert imported["source_sha256"] == sha256_file(src)
    assert imported["sparse_layout"] == layout
    assert imported["rulebooks"] == ("spconv1-shared" if layout == "spconv1" else "per-layer")
    assert imported["top_level_keys"] == NETWORKS["dsnet"]["top_level_keys"]
    assert imported["dropped"]["training_buffers"] == [
        {
            "key": "sem_loss.weight",
            "shape": [20],
            "about": "class weights of the semantic loss (CrossEntropyLoss), used in training only",
        }
    ]
    assert imported["reference_epoch"] == 7 and imported["bandwidths"] == [0.2, 1.7, 3.2]
    assert card.architecture["grid"]["convention"] == "reference"
    points = scan(0)
    (logits, offsets), got, _ = run_both(ref, tmp_path / "ckpt", points, spconv1=layout == "spconv1")
    assert float(logits.abs().max()) > 0.1 and float(offsets.abs().max()) > 0.1  # not vacuous
    torch.testing.assert_close(got.logits, logits, atol=1e-4, rtol=0)
    torch.testing.assert_close(got.offsets, offsets, atol=1e-4, rtol=0)
    shift = load_shift_weights(tmp_path / "ckpt")
    ref_mlp = ref.pytorch_meanshift.learnable_bandwidth_weights_layer_list
    for i in range(4):
        assert torch.equal(shift[f"mlps.{i}.1.running_var"], ref_mlp[i][1].running_var)
        assert torch.equal(shift[f"mlps.{i}.3.weight"], ref_mlp[i][3].weight)


def test_shared_rulebooks_matter(tmp_path):
    """A spconv 1.x file run with per-layer rulebooks does not give the reference's outputs."""
    ref = randomize(DSNetReference(4), seed=2)
    src = save_reference(ref, tmp_path / "dsnet.pth", "spconv1", wrapped=True)
    import_checkpoint(src, tmp_path / "ckpt", "dsnet", rulebooks="per-layer")
    (logits, _), got, _ = run_both(ref, tmp_path / "ckpt", scan(1), spconv1=True)
    assert float((got.logits - logits).abs().max()) > 1e-2


def test_dsnet4d_bandwidths_and_cylinder3d_semantic_only(tmp_path):
    ref = randomize(DSNetReference(4), seed=3)
    card = import_checkpoint(
        save_reference(ref, tmp_path / "d4.pth", "spconv1", True), tmp_path / "d4", "dsnet4d"
    )
    assert card.training_data["imported"]["bandwidths"] == [0.2, 1.8, 3.4]
    cyl = randomize(Cylinder3DReference(4), seed=4)
    src = save_reference(cyl, tmp_path / "cyl.pt", "spconv1", wrapped=False)
    card = import_checkpoint(src, tmp_path / "cyl", "cylinder3d")
    assert card.training_data["imported"]["semantic_only"] is True
    assert card.architecture["point_mlp"][-1] == 256 and card.architecture["grid"]["min_bound"][2] == -4.0
    assert load_shift_weights(tmp_path / "cyl") is None
    (logits, _), got, _ = run_both(cyl, tmp_path / "cyl", scan(2), spconv1=True)
    torch.testing.assert_close(got.logits, logits, atol=1e-4, rtol=0)


@pytest.mark.parametrize("convention", ["reference", "ours"])
def test_grid_conventions_match_the_reference_arithmetic(convention):
    grid = CylinderGrid(convention=convention)
    lo, hi = np.array(grid.min_bound), np.array(grid.max_bound)
    step = np.array(grid.interval)
    assert np.allclose(step, (hi - lo) / (np.array(grid.size) - (convention == "reference")))
    points = scan(3)
    edge = np.array([[50.0, 0.0, 1.5, 0.2], [60.0, 1.0, 3.0, 0.1], [3.0, 0.0, -3.0, 0.0]], np.float32)
    points = np.concatenate([points, edge])
    want_cells, want_feats = reference_features(points, grid)
    cells, feats = cylinder_features(torch.from_numpy(points), grid)
    assert np.array_equal(cells.numpy(), want_cells)
    np.testing.assert_allclose(feats.numpy(), want_feats, atol=1e-5 if convention == "ours" else 0, rtol=0)
    assert torch.equal(cells[-3, [0, 2]], cells[-2, [0, 2]])  # beyond max: clamped onto max


def test_conventions_place_points_differently():
    points = torch.from_numpy(scan(4))
    ours, _ = cylinder_features(points, CylinderGrid())
    ref, _ = cylinder_features(points, CylinderGrid(convention="reference"))
    assert (ours != ref).any(dim=1).float().mean() > 0.1


def test_default_config_dicts_are_unchanged():
    from dsnet_core.model.presets import PRESETS

    assert "convention" not in PRESETS["tiny"].grid.to_dict() and "rulebooks" not in PRESETS["tiny"].to_dict()
    assert PRESETS["reference"].to_dict()["rulebooks"] == "spconv1-shared"


def test_unsafe_pickle_is_refused(tmp_path):
    src = tmp_path / "evil.pth"
    torch.save({"model_state": {"a": torch.zeros(1)}, "other_state": Path("x")}, src)
    with pytest.raises(CheckpointImportError, match=r"weights_only=True.*no fallback"):
        import_checkpoint(src, tmp_path / "out", "dsnet")
    assert not (tmp_path / "out").exists()


def small_state(seed: int) -> dict[str, torch.Tensor]:
    return spconv1_state(randomize(DSNetReference(4), seed=seed).state_dict())


def refusal(state: dict, tmp_path: Path, kind: str = "dsnet") -> str:
    torch.save({"epoch": 1, "model_state": state}, tmp_path / "bad.pth")
    with pytest.raises(CheckpointImportError) as err:
        import_checkpoint(tmp_path / "bad.pth", tmp_path / "out", kind)
    assert not (tmp_path / "out").exists()
    msg = str(err.value)
    assert msg.startswith(f"{tmp_path / 'bad.pth'}: ") and "\n" not in msg
    return msg


def test_bad_keys_are_listed(tmp_path):
    state = small_state(5)
    state["backbone.extra.weight"] = torch.zeros(3)
    state["sem_loss.pos_weight"] = torch.ones(20)  # a loss buffer the reference does not register
    del state["backbone.upBlock1.bn2.running_var"]
    del state["ins_head.offset_linear.weight"]
    state["sem_head.logits.weight"] = state["sem_head.logits.weight"][..., :5]
    msg = refusal(state, tmp_path)
    assert "does not match the dsnet reference network" in msg
    assert "unknown keys (2): backbone.extra.weight, sem_loss.pos_weight" in msg
    assert "missing keys (2): backbone.upBlock1.bn2.running_var, ins_head.offset_linear.weight" in msg
    assert "mis-shaped keys (1): sem_head.logits.weight" in msg


def test_a_training_buffer_is_recognised_by_its_shape_too(tmp_path):
    state = small_state(6)
    state["sem_loss.weight"] = torch.ones(19)
    msg = refusal(state, tmp_path)
    assert msg.endswith(
        "mis-shaped keys (1): sem_loss.weight (19,) (expected (20,): the class weights of the semantic "
        "loss (CrossEntropyLoss))"
    )
    del state["sem_loss.weight"]  # a file without it (a re-saved network) imports
    torch.save({"model_state": state}, tmp_path / "ok.pth")
    card = import_checkpoint(tmp_path / "ok.pth", tmp_path / "ok", "dsnet")
    assert card.training_data["imported"]["dropped"]["training_buffers"] == []


def test_non_finite_weights_are_refused(tmp_path):
    state = {
        k: v.float().fill_(float("nan")) if v.is_floating_point() else v for k, v in small_state(7).items()
    }
    msg = refusal(state, tmp_path)
    assert "NaN or infinite weights in keys (" in msg
    first = [k for k, v in state.items() if v.is_floating_point() and k != "sem_loss.weight"][:12]
    assert msg.endswith(f"): {', '.join(first)} …")
    state = small_state(7)
    state["ins_head.bn2.running_var"][3] = float("inf")
    state["sem_loss.weight"][0] = float("nan")  # dropped, not used: not a reason to refuse
    assert refusal(state, tmp_path).endswith(
        ": NaN or infinite weights in keys (1): ins_head.bn2.running_var"
    )


def test_semantic_only_file_as_dsnet_is_refused_with_a_hint(tmp_path):
    cyl = randomize(Cylinder3DReference(4), seed=6)
    torch.save(cyl.state_dict(), tmp_path / "cyl.pt")
    with pytest.raises(CheckpointImportError, match="semantic-only file imports with kind 'cylinder3d'"):
        import_checkpoint(tmp_path / "cyl.pt", tmp_path / "out", "dsnet")


def test_ambiguous_layout_is_refused():
    """A weight whose shape reads the same in both layouts (in = out = every kernel side)."""
    from dsnet_core.model.reference_convert import _detect_layout
    from dsnet_core.model.reference_names import Target

    targets = {"x": Target("y", "sparse", (3, 3, 3))}
    ours = {"y.weight": torch.empty(27, 3, 3)}
    with pytest.raises(CheckpointImportError, match=r"cannot tell spconv 1\.x"):
        _detect_layout({"x.weight": torch.empty(3, 3, 3, 3, 3)}, targets, ours, "auto", Path("f.pth"))
    assert (
        _detect_layout({"x.weight": torch.empty(3, 3, 3, 3, 3)}, targets, ours, "spconv2", Path("f"))
        == "spconv2"
    )
    assert math.prod((3, 3, 3)) == 27


def test_equivariant_lifting_refuses_the_reference_grid_only():
    from dsnet_core.errors import ConfigError
    from dsnet_core.model.equivariant import check_equivariant_grid

    check_equivariant_grid(CylinderGrid(), 4)
    with pytest.raises(ConfigError, match="convention"):
        check_equivariant_grid(CylinderGrid(convention="reference"), 4)


def test_numpy_scalars_of_old_pickles_are_allowed(tmp_path):
    """The reference's other_state may hold numpy scalars, pickled under numpy 1.x's module name."""
    import io

    from dsnet_core.model.reference_file import load_reference_file

    buf = io.BytesIO()
    obj = {"epoch": 3, "model_state": {"a": torch.ones(2)}, "other_state": {"best_pq": np.float64(0.5)}}
    torch.save(obj, buf, _use_new_zipfile_serialization=False)  # protocol 2: GLOBAL module\nname
    raw = buf.getvalue().replace(b"numpy._core.multiarray\nscalar", b"numpy.core.multiarray\nscalar")
    assert b"numpy.core.multiarray\nscalar" in raw
    (tmp_path / "old.pth").write_bytes(raw)
    state, info = load_reference_file(tmp_path / "old.pth")
    assert torch.equal(state["a"], torch.ones(2)) and info["epoch"] == 3
