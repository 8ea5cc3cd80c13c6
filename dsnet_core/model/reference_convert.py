"""Convert a released reference checkpoint's state dict (DS-Net, 4D-DS-Net, Cylinder3D) to this
project's network; :mod:`dsnet_core.model.reference_file` reads the file and
:mod:`dsnet_core.model.importer` writes the result as a checkpoint.

What happens, in order:

1. (reading: :func:`~dsnet_core.model.reference_file.load_reference_file`);
2. its state dict (the reference's ``model_state``, or a bare state dict) is matched against the
   reference's module names (:mod:`dsnet_core.model.reference_names`); the widths come from its
   shapes, the rest of the architecture from the ``reference`` / ``cylinder3d`` preset;
3. sparse-convolution weights are converted from spconv 1.x ``(*kernel, in, out)`` or 2.x
   ``(out, *kernel, in)`` layout, told apart by shape (refused when every weight fits both);
   a 1.x file was trained with spconv 1.x's shared rulebooks and is imported with
   ``rulebooks="spconv1-shared"`` (see :mod:`dsnet_core.model.backbone`), a 2.x file per layer;
4. BatchNorm statistics, linear layers and the shifting MLPs are copied; the reference's
   training-only buffers (:func:`~dsnet_core.model.reference_names.training_buffers`: DS-Net's
   semantic-loss class weights), recognised by name and shape, are dropped and listed; every
   unknown, missing or mis-shaped key, and every weight holding NaN or infinity, is collected and
   reported in one :class:`CheckpointImportError`.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from dsnet_core.errors import CheckpointImportError
from dsnet_core.model.network import DSNet
from dsnet_core.model.presets import CYLINDER3D, REFERENCE, ModelConfig
from dsnet_core.model.reference_names import (
    BN_FIELDS,
    Target,
    reference_modules,
    split_key,
    training_buffers,
)

KINDS = ("dsnet", "dsnet4d", "cylinder3d")
LAYOUTS = ("auto", "spconv1", "spconv2")
BANDWIDTHS = {"dsnet": (0.2, 1.7, 3.2), "dsnet4d": (0.2, 1.8, 3.4)}
_FIELDS = {"sparse": ("weight", "bias"), "linear": ("weight", "bias"), "bn": BN_FIELDS}


def _scheme(state: dict) -> str:
    return "cylinder3d" if any(k.startswith("cylinder_3d_") for k in state) else "dsnet"


def _infer_config(state: dict, scheme: str, kind: str, src: Path) -> tuple[ModelConfig, int, int]:
    """Widths from the shapes (never from sparse weights, whose layout is not known yet).

    Returns:
        (config, point-MLP linear layers, shifting iterations present).
    """
    pre, bb = ("cylinder_3d_generator.", "cylinder_3d_spconv_seg.") if scheme == "cylinder3d" else ("", "")
    bb = bb or "backbone."
    logits = "cylinder_3d_spconv_seg.logits.bias" if scheme == "cylinder3d" else "sem_head.logits.bias"
    mlp = f"{pre}PPmodel" if scheme == "cylinder3d" else "vfe_model.PPmodel"
    needed = [f"{bb}downCntx.bn0.weight", f"{pre}fea_compression.0.weight", logits, f"{mlp}.1.weight"]
    absent = [k for k in needed if k not in state]
    if absent:
        raise CheckpointImportError(src, f"not a {kind} reference checkpoint: missing keys {absent}")
    widths, j = [], 1
    while f"{mlp}.{j}.weight" in state:
        widths.append(int(state[f"{mlp}.{j}.weight"].shape[0]))
        j += 3
    width = int(state[f"{bb}downCntx.bn0.weight"].shape[0])
    ins = state.get("ins_head.bn3.weight")
    iterations = 0
    while f"pytorch_meanshift.learnable_bandwidth_weights_layer_list.{iterations}.0.weight" in state:
        iterations += 1
    base = CYLINDER3D if kind == "cylinder3d" else REFERENCE
    config = replace(
        base,
        width=width,
        num_classes=int(state[logits].shape[0]),
        point_mlp=tuple(widths),
        compress=int(state[f"{pre}fea_compression.0.weight"].shape[0]),
        ins_dim=int(ins.shape[0]) if ins is not None else width,
    )
    return config, len(widths), iterations


def _layout_fits(shape: tuple, kernel: tuple, cin: int, cout: int) -> set[str]:
    fits = set()
    if shape == (*kernel, cin, cout):
        fits.add("spconv1")
    if shape == (cout, *kernel, cin):
        fits.add("spconv2")
    return fits


def _detect_layout(
    state: dict, targets: dict[str, Target], ours: dict[str, torch.Tensor], layout: str, src: Path
) -> str:
    """One layout for the whole file: the one every sparse weight fits and some fit only."""
    decisive: dict[str, list[str]] = {"spconv1": [], "spconv2": []}
    fits_all = {"spconv1", "spconv2"}
    for module, t in targets.items():
        key, our_key = f"{module}.weight", f"{t.module}.weight"
        if t.kind != "sparse" or key not in state or our_key not in ours:
            continue
        _, cin, cout = ours[our_key].shape
        fits = _layout_fits(tuple(state[key].shape), t.kernel, cin, cout)
        fits_all &= fits if fits else fits_all  # mis-shaped weights are reported later
        if len(fits) == 1:
            decisive[fits.pop()].append(key)
    if layout != "auto":
        return layout
    found = [name for name, keys in decisive.items() if keys]
    if len(found) == 2:
        raise CheckpointImportError(
            src,
            f"sparse weights in both layouts: spconv 1.x {decisive['spconv1'][:3]}, "
            f"spconv 2.x {decisive['spconv2'][:3]}",
        )
    if not found:
        raise CheckpointImportError(
            src,
            "cannot tell spconv 1.x (*kernel, in, out) from 2.x (out, *kernel, in): every sparse "
            "weight has a shape valid in both; pass the layout explicitly (--layout spconv1|spconv2)",
        )
    return found[0]


def _to_ours(w: torch.Tensor, layout: str, kernel: tuple, taps: int) -> torch.Tensor:
    """A reference sparse weight → ``(taps, in, out)``, kernel taps in row-major order; the first
    ``taps`` taps when spconv 1.x's shared rulebook used fewer than the declared kernel has."""
    k = int(np.prod(kernel))
    flat = w.reshape(k, w.shape[-2], w.shape[-1]) if layout == "spconv1" else w.permute(1, 2, 3, 4, 0)
    return flat.reshape(k, flat.shape[-2], flat.shape[-1])[:taps]


def _shift_expected(config: ModelConfig, iterations: int) -> dict[str, tuple]:
    """``shift.mlps.{i}.{j}.*`` → shape of the shifting MLPs' tensors (none when ``iterations`` is 0)."""
    d, out = config.ins_dim, {}
    for i in range(iterations):
        for j, shape in ((0, (d, d)), (1, (d,)), (3, (len(BANDWIDTHS["dsnet"]), d))):
            out |= {f"shift.mlps.{i}.{j}.weight": shape, f"shift.mlps.{i}.{j}.bias": shape[:1]}
        out |= {f"shift.mlps.{i}.1.{f}": (d,) for f in BN_FIELDS[2:4]}
        out[f"shift.mlps.{i}.1.num_batches_tracked"] = ()
    return out


def _listed(label: str, keys: list[str]) -> str:
    return f"{label} ({len(keys)}): {', '.join(keys[:12])}{' …' if len(keys) > 12 else ''}"


def _non_finite(value: torch.Tensor) -> bool:
    """Whether ``value`` holds a NaN or an infinity: a finite sum proves it does not (a NaN or an
    infinity anywhere makes the sum non-finite; 13 ms for 56 M floats against 1 s for an
    element-wise check); a non-finite sum may be an overflow of finite values and is checked."""
    if not value.is_floating_point() or value.is_meta or bool(torch.isfinite(value.sum())):
        return False
    return not bool(torch.isfinite(value).all())


def convert_state(
    state: dict[str, torch.Tensor],
    kind: str,
    src: Path,
    layout: str = "auto",
    rulebooks: str = "auto",
) -> tuple[ModelConfig, dict[str, torch.Tensor], dict[str, torch.Tensor], dict]:
    """Map a reference state dict onto this project's network.

    Args:
        state: the reference's state dict.
        kind: one of :data:`KINDS`.
        src: the file (named in errors).
        layout: one of :data:`LAYOUTS`.
        rulebooks: ``"auto"`` (from the layout), ``"spconv1-shared"`` or ``"per-layer"``.

    Returns:
        (config, network state, shifting-MLP state (empty when absent), a summary for the card:
        naming, layout, rulebooks, counts and ``dropped`` — the training-only buffers and the kernel
        taps left out).

    Raises:
        CheckpointImportError: listing every unknown, missing and mis-shaped key and every weight
            with NaN or infinite values.
    """
    if kind not in KINDS:
        raise CheckpointImportError(src, f"unknown kind {kind!r} (choose from {', '.join(KINDS)})")
    if layout not in LAYOUTS:
        raise CheckpointImportError(src, f"unknown layout {layout!r} (choose from {', '.join(LAYOUTS)})")
    scheme = _scheme(state)
    config, n_linear, iterations = _infer_config(state, scheme, kind, src)
    targets = reference_modules(scheme, n_linear, max(iterations, 4))
    with torch.device("meta"):
        probe = DSNet(replace(config, rulebooks="per-layer")).state_dict()
    layout = _detect_layout(state, targets, probe, layout, src)
    if rulebooks == "auto":
        rulebooks = "spconv1-shared" if layout == "spconv1" else "per-layer"
    config = replace(config, rulebooks=rulebooks)
    torch.manual_seed(0)  # only the untrained instance head of a semantic-only import keeps these
    ours = DSNet(config).state_dict()
    shift_expected = _shift_expected(config, iterations)
    buffers = training_buffers(scheme, config.num_classes)
    out, shift = {}, {}
    unknown, misshaped, non_finite, taps, dropped = [], [], [], [], []
    seen: set[str] = set()  # our keys of mis-shaped reference keys (reported once, not as missing)
    counts = {"sparse": 0, "bn": 0, "linear": 0}
    for key, value in state.items():
        if key in buffers:
            shape, about = buffers[key]
            if tuple(value.shape) == shape:
                dropped.append({"key": key, "shape": list(shape), "about": f"{about}, used in training only"})
            else:
                misshaped.append(f"{key} {tuple(value.shape)} (expected {shape}: the {about})")
            continue
        module, field = split_key(key)
        t = targets.get(module)
        if t is None or field not in _FIELDS[t.kind] or (kind == "cylinder3d" and t.part != "semantic"):
            unknown.append(key)
            continue
        our_key = f"{t.module}.{field}"
        if t.part == "shift" and our_key not in shift_expected:
            unknown.append(key)
            continue
        expected = tuple(shift_expected[our_key] if t.part == "shift" else ours[our_key].shape)
        if t.kind == "sparse" and field == "weight":
            n_taps, cin, cout = expected
            if layout not in _layout_fits(tuple(value.shape), t.kernel, cin, cout) or n_taps > np.prod(
                t.kernel
            ):
                misshaped.append(
                    f"{key} {tuple(value.shape)} (expected {layout} layout of {t.kernel}, {cin}→{cout})"
                )
                seen.add(our_key)
                continue
            if n_taps < np.prod(t.kernel):
                taps.append(key)
            value = _to_ours(value, layout, t.kernel, n_taps)
        if tuple(value.shape) != expected:
            misshaped.append(f"{key} {tuple(value.shape)} (expected {expected})")
            seen.add(our_key)
            continue
        if _non_finite(value):
            non_finite.append(key)
        (shift if t.part == "shift" else out)[our_key.removeprefix("shift.")] = value.detach().clone()
        counts[t.kind] += field == "weight"
    optional = ("ins_head.",) if kind == "cylinder3d" else ()
    names = {f"{t.module}.{f}": f"{m}.{f}" for m, t in targets.items() for f in _FIELDS[t.kind]}
    missing = sorted(  # named as in the reference's file
        names.get(k, k)
        for k in [k for k in ours if k not in out and k not in seen and not k.startswith(optional)]
        + [k for k in shift_expected if k.removeprefix("shift.") not in shift and k not in seen]
    )
    problems = [
        _listed(label, keys)
        for label, keys in (
            ("unknown keys", unknown),
            ("missing keys", missing),
            ("mis-shaped keys", misshaped),
        )
        if keys
    ]
    if problems:
        hint = ""
        if kind != "cylinder3d" and any(k.startswith("ins_head.") for k in missing):
            hint = " (a semantic-only file imports with kind 'cylinder3d')"
        raise CheckpointImportError(
            src, f"does not match the {kind} reference network{hint}: " + "; ".join(problems)
        )
    if non_finite:
        raise CheckpointImportError(src, _listed("NaN or infinite weights in keys", non_finite))
    for k in ours:
        out.setdefault(k, ours[k])
    summary = {
        "naming": scheme,
        "sparse_layout": layout,
        "rulebooks": rulebooks,
        "converted": {
            "sparse_convolutions": counts["sparse"],
            "batch_norms": counts["bn"],
            "linear_layers": counts["linear"],
            "shifting_iterations": iterations,
        },
        "dropped": {"training_buffers": dropped, "kernel_taps": taps},
        "semantic_only": kind == "cylinder3d",
    }
    return config, out, shift, summary
