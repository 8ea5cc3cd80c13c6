"""The checkpoint importer against a reconstruction of the reference networks in spconv 2.x.

Verified against a reconstruction written from the reference's public model definitions (pinned by
``fixtures/reference_parameters.json``), not against the released files, which cannot be fetched
here. The numeric comparison uses a small width (4) of the same architecture; the full-width name
and shape lists are checked against the fixture.
"""

from __future__ import annotations

import json
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
from dsnet_core.model.presets import CYLINDER3D, REFERENCE
from dsnet_core.model.reference_convert import convert_state
from tests.dsnet_core.model.reference_net import (
    Cylinder3DReference,
    DSNetReference,
    Run,
    randomize,
    reference_features,
    spconv1_state,
)

FIXTURE = json.loads((Path(__file__).parent / "fixtures" / "reference_parameters.json").read_text())


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


@pytest.mark.parametrize(("name", "cls"), [("dsnet", DSNetReference), ("cylinder3d", Cylinder3DReference)])
def test_reconstruction_has_the_reference_parameters(name, cls):
    with torch.device("meta"):
        net = cls(32)
    assert shapes_in_spconv1(net) == {k: s for k, s in FIXTURE[name]["parameters"]}


@pytest.mark.parametrize(("name", "preset"), [("dsnet", REFERENCE), ("cylinder3d", CYLINDER3D)])
def test_full_width_reference_maps_onto_the_preset(name, preset):
    state = {k: torch.empty(s, device="meta") for k, s in FIXTURE[name]["parameters"]}
    kind = "dsnet" if name == "dsnet" else "cylinder3d"
    config, _, shift, summary = convert_state(state, kind, Path(f"{name}.pth"))
    assert config == preset
    assert summary["sparse_layout"] == "spconv1" and summary["rulebooks"] == "spconv1-shared"
    assert summary["taps_dropped"] == [
        f"{'backbone' if kind == 'dsnet' else 'cylinder_3d_spconv_seg'}.upBlock{i}.conv3.weight"
        for i in range(4)
    ]
    assert len(shift) == (4 * 9 if kind == "dsnet" else 0)


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
    assert imported["top_level_keys"] == FIXTURE["dsnet"]["top_level_keys"]
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


def test_bad_keys_are_listed(tmp_path):
    ref = randomize(DSNetReference(4), seed=5)
    state = spconv1_state(ref.state_dict())
    state["backbone.extra.weight"] = torch.zeros(3)
    del state["backbone.upBlock1.bn2.running_var"]
    state["sem_head.logits.weight"] = state["sem_head.logits.weight"][..., :5]
    torch.save({"epoch": 1, "model_state": state}, tmp_path / "bad.pth")
    with pytest.raises(CheckpointImportError) as err:
        import_checkpoint(tmp_path / "bad.pth", tmp_path / "out", "dsnet")
    msg = str(err.value)
    assert "bad.pth" in msg and "unknown keys (1): backbone.extra.weight" in msg
    assert "missing keys (1): backbone.up.1.c2.bn.running_var" in msg
    assert "mis-shaped keys (1): sem_head.logits.weight" in msg


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

    from dsnet_core.model.reference_convert import load_reference_file

    buf = io.BytesIO()
    obj = {"epoch": 3, "model_state": {"a": torch.ones(2)}, "other_state": {"best_pq": np.float64(0.5)}}
    torch.save(obj, buf, _use_new_zipfile_serialization=False)  # protocol 2: GLOBAL module\nname
    raw = buf.getvalue().replace(b"numpy._core.multiarray\nscalar", b"numpy.core.multiarray\nscalar")
    assert b"numpy.core.multiarray\nscalar" in raw
    (tmp_path / "old.pth").write_bytes(raw)
    state, info = load_reference_file(tmp_path / "old.pth")
    assert torch.equal(state["a"], torch.ones(2)) and info["epoch"] == 3
