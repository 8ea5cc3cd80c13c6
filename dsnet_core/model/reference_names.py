"""The released reference networks' module names and what they are in this project.

Facts from the public model definitions (hongfz16/DS-Net ``network/model_zoo.py``,
``network/modules/{spconv_unet,PointNet,pytorch_meanshift}.py``; xinge008/Cylinder3D
``network/{cylinder_spconv_3d,segmentator_3d_asymm_spconv,cylinder_fea_generator}.py``). What the
reference networks register, as instantiated from those commits (every parameter and buffer with its
shape), is pinned by ``tests/dsnet_core/model/fixtures/reference_state_dicts.json``.

Two naming schemes hold the same backbone:

- ``"dsnet"``: ``vfe_model.PPmodel``, ``fea_compression``, ``backbone``, ``sem_head.logits``,
  ``ins_head``, ``pytorch_meanshift.learnable_bandwidth_weights_layer_list`` (DS-Net, 4D-DS-Net);
- ``"cylinder3d"``: ``cylinder_3d_generator.{PPmodel,fea_compression}`` and
  ``cylinder_3d_spconv_seg`` (backbone and ``logits``) (Cylinder3D).

Besides the modules the network runs, DS-Net registers its semantic loss, a ``CrossEntropyLoss``
with class weights, as the submodule ``sem_loss``: its ``weight`` buffer, one weight per class, is in
every file it saves and means nothing at inference (:func:`training_buffers`). Cylinder3D keeps its
losses outside the network and registers no such buffer.
"""

from __future__ import annotations

from dataclasses import dataclass

Kernel = tuple[int, int, int]
K133, K313, K333 = (1, 3, 3), (3, 1, 3), (3, 3, 3)
SCHEMES = ("dsnet", "cylinder3d")
BN_FIELDS = ("weight", "bias", "running_mean", "running_var", "num_batches_tracked")


@dataclass(frozen=True)
class Target:
    """Where one reference module goes.

    Attributes:
        module: this project's module path (``backbone.context.a1.conv``) or, for the shifting
            MLPs, ``shift.`` + the path inside :class:`~dsnet_core.instance.shifting.DynamicShift`.
        kind: ``"sparse"`` (sparse-convolution weight, maybe bias), ``"bn"``, ``"linear"``.
        kernel: the reference's declared kernel of a sparse convolution (None otherwise).
        part: ``"semantic"``, ``"instance"`` or ``"shift"`` (which kinds of checkpoint carry it).
    """

    module: str
    kind: str
    kernel: Kernel | None = None
    part: str = "semantic"


def _conv_bn(ref: str, ours: str, conv: str, bn: str, kernel: Kernel, part: str = "semantic") -> dict:
    return {
        f"{ref}.{conv}": Target(f"{ours}.conv", "sparse", kernel, part),
        f"{ref}.{bn}": Target(f"{ours}.bn", "bn", None, part),
    }


def _backbone(ref: str) -> dict[str, Target]:
    """``downCntx``, ``resBlock2..5``, ``upBlock0..3``, ``ReconNet`` → ``backbone.*``."""
    out: dict[str, Target] = {}
    ctx = f"{ref}.downCntx"
    for conv, bn, ours, k in (
        ("conv1", "bn0", "a1", K133),
        ("conv1_2", "bn0_2", "a2", K313),
        ("conv2", "bn1", "b1", K313),
        ("conv3", "bn2", "b2", K133),
    ):
        out |= _conv_bn(ctx, f"backbone.context.{ours}", conv, bn, k)
    for i in range(4):
        blk, ours = f"{ref}.resBlock{i + 2}", f"backbone.down.{i}"
        for conv, bn, a, k in (
            ("conv1", "bn0", "a1", K313),
            ("conv1_2", "bn0_2", "a2", K133),
            ("conv2", "bn1", "b1", K133),
            ("conv3", "bn2", "b2", K313),
        ):
            out |= _conv_bn(blk, f"{ours}.res.{a}", conv, bn, k)
        out[f"{blk}.pool"] = Target(f"{ours}.pool", "sparse", K333)
    for i in range(4):
        blk, ours = f"{ref}.upBlock{i}", f"backbone.up.{i}"
        out |= _conv_bn(blk, f"{ours}.trans", "trans_dilao", "trans_bn", K333)
        for conv, bn, c, k in (
            ("conv1", "bn1", "c1", K133),
            ("conv2", "bn2", "c2", K313),
            ("conv3", "bn3", "c3", K333),
        ):
            out |= _conv_bn(blk, f"{ours}.{c}", conv, bn, k)
        out[f"{blk}.up_subm"] = Target(f"{ours}.up", "sparse", K333)
    for j, (conv, bn, k) in enumerate(
        (("conv1", "bn0", (3, 1, 1)), ("conv1_2", "bn0_2", (1, 3, 1)), ("conv1_3", "bn0_3", (1, 1, 3)))
    ):
        out |= _conv_bn(f"{ref}.ReconNet", f"backbone.recon.branches.{j}", conv, bn, k)
    return out


def _point_mlp(ref: str, n_linear: int) -> dict[str, Target]:
    """``PPmodel``: BN, then (Linear, BN, ReLU) × (n − 1), Linear: same indices as ``point_encoder.mlp``."""
    out = {f"{ref}.0": Target("point_encoder.mlp.0", "bn")}
    for j in range(n_linear):
        out[f"{ref}.{1 + 3 * j}"] = Target(f"point_encoder.mlp.{1 + 3 * j}", "linear")
        if j < n_linear - 1:
            out[f"{ref}.{2 + 3 * j}"] = Target(f"point_encoder.mlp.{2 + 3 * j}", "bn")
    return out


def reference_modules(scheme: str, n_linear: int = 4, iterations: int = 4) -> dict[str, Target]:
    """Every reference module of a naming scheme → its :class:`Target`.

    Args:
        scheme: one of :data:`SCHEMES`.
        n_linear: linear layers of the point MLP (4 in both references).
        iterations: shifting iterations (4 in DS-Net).
    """
    if scheme == "cylinder3d":
        out = _point_mlp("cylinder_3d_generator.PPmodel", n_linear)
        out["cylinder_3d_generator.fea_compression.0"] = Target("point_encoder.compress.0", "linear")
        out |= _backbone("cylinder_3d_spconv_seg")
        out["cylinder_3d_spconv_seg.logits"] = Target("sem_head.conv", "sparse", K333)
        return out
    if scheme != "dsnet":
        raise ValueError(f"unknown naming scheme {scheme!r}")
    out = _point_mlp("vfe_model.PPmodel", n_linear)
    out["fea_compression.0"] = Target("point_encoder.compress.0", "linear")
    out |= _backbone("backbone")
    out["sem_head.logits"] = Target("sem_head.conv", "sparse", K333)
    for j in range(3):
        out |= _conv_bn("ins_head", f"ins_head.convs.{j}", f"conv{j + 1}", f"bn{j + 1}", K333, "instance")
    out["ins_head.offset.0"] = Target("ins_head.offset.0", "linear", None, "instance")
    out["ins_head.offset.1"] = Target("ins_head.offset.1", "bn", None, "instance")
    out["ins_head.offset_linear"] = Target("ins_head.offset.3", "linear", None, "instance")
    for i in range(iterations):
        ref = f"pytorch_meanshift.learnable_bandwidth_weights_layer_list.{i}"
        for j, kind in ((0, "linear"), (1, "bn"), (3, "linear")):
            out[f"{ref}.{j}"] = Target(f"shift.mlps.{i}.{j}", kind, None, "shift")
    return out


@dataclass(frozen=True)
class TrainingBuffer:
    """A buffer a reference network registers for training only; the importer drops it.

    Attributes:
        key: its state-dict key.
        shape: ``"classes"`` (one value per output class) — the only shape such buffers have.
        about: what it is, for the card and the command's output.
    """

    key: str
    shape: str
    about: str


_TRAINING_BUFFERS = {
    "dsnet": (
        TrainingBuffer("sem_loss.weight", "classes", "class weights of the semantic loss (CrossEntropyLoss)"),
    ),
    "cylinder3d": (),
}


def training_buffers(scheme: str, num_classes: int) -> dict[str, tuple[tuple[int, ...], str]]:
    """The training-only buffers of a naming scheme: key → (shape, what it is).

    Args:
        scheme: one of :data:`SCHEMES`.
        num_classes: the network's output classes (the length of a class-weight buffer).
    """
    shapes = {"classes": (num_classes,)}
    return {b.key: (shapes[b.shape], b.about) for b in _TRAINING_BUFFERS[scheme]}


def split_key(key: str) -> tuple[str, str]:
    """``"a.b.weight"`` → ``("a.b", "weight")``."""
    module, _, field = key.rpartition(".")
    return module, field
