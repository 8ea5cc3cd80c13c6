"""Inference API used by the ``infer`` stage: points (or a 4D volume) → per-point semantic
prediction, probabilities, offsets and instance features."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from dsnet_core.errors import DataFormatError
from dsnet_core.labels import LabelMap
from dsnet_core.model.checkpoint import ModelCard, load_checkpoint
from dsnet_core.model.network import DSNet
from dsnet_core.model.tta import TTAConfig, tta_forward

if TYPE_CHECKING:
    from dsnet_core.model.sensor_match import SensorMatch

ARGMAX_RULES = ("labelled", "all")
"""How a point's class is taken from its logits (:class:`Predictor`'s ``argmax``)."""


@dataclass(frozen=True)
class InferenceResult:
    """Per-point outputs of one cloud (or one 4D volume).

    Attributes:
        sem: int64 ``(N,)`` predicted train id (argmax over classes 1..C-1, 0 never predicted; over
            0..C-1 with ``argmax="all"``).
        probs: float16 ``(N, C)`` softmax probabilities.
        offsets: float32 ``(N, 3)`` metres, point → predicted instance centre.
        features: float16 ``(N, D)`` instance features for the shifting module (D = 32).
    """

    sem: np.ndarray
    probs: np.ndarray
    offsets: np.ndarray
    features: np.ndarray


@dataclass(frozen=True)
class StoredResult:
    """Per-point outputs of one cloud as the ``infer`` stage stores them.

    Attributes:
        sem: int64 ``(N,)`` predicted train id.
        probs: uint8 ``(N, C)`` the float16 softmax probabilities quantised (:func:`quantise`).
        offsets: float32 ``(N, 3)`` metres, on the kept points; 0 elsewhere.
        features: float16 ``(N, D)`` instance features, on the kept points; 0 elsewhere.
        kept: bool ``(N,)`` the points whose class was kept.
    """

    sem: np.ndarray
    probs: np.ndarray
    offsets: np.ndarray
    features: np.ndarray
    kept: np.ndarray


def sensor_match(path: str | Path, card: ModelCard, mode: str) -> SensorMatch | None:
    """The ``match`` transform of checkpoint ``path`` (None for ``"none"``, and for ``"auto"`` where
    the card's :func:`~dsnet_core.model.sensor_match.auto_mode` says ``none``).

    Raises:
        ConfigError: an unknown mode, or a card without ``training_data.sensor_reference``.
    """
    from dsnet_core.errors import ConfigError
    from dsnet_core.model.sensor_match import MATCH_MODES, SensorMatch, auto_mode, card_reference

    if mode not in MATCH_MODES:
        raise ConfigError(f"--match {mode!r}: choose one of {', '.join(MATCH_MODES)}")
    if mode == "auto":
        mode = auto_mode(card.training_data or {})
    if mode == "none":
        return None
    ref = card_reference(card.training_data or {}, f"{path}/card.json")
    if ref is None:
        raise ConfigError(
            f"--match {mode}: checkpoint {path} records no sensor reference (training_data.sensor_reference "
            "in its card; `dsnet train` writes it): label it without --match"
        )
    return SensorMatch(ref, mode)


def quantise(probs: torch.Tensor) -> torch.Tensor:
    """Probabilities in [0, 1] → uint8 ``round(p * 255)`` (a new tensor)."""
    return probs.to(torch.float32, copy=True).mul_(255.0).round_().clamp_(0, 255).to(torch.uint8)


class Predictor:
    """Runs a trained :class:`DSNet` on point clouds.

    Args:
        model: the network (put in eval mode here).
        card: its model card.
        device: ``"cpu"`` or ``"cuda"``.
        threads: torch CPU threads for this process (one by default; None leaves it unchanged).
        tta: test-time augmentation (:mod:`dsnet_core.model.tta`); None or one rotation without
            flips is the plain forward pass.
        argmax: ``"labelled"`` (default): each point's class is the argmax over classes 1..C-1, so
            0 ("unlabelled") is never predicted; ``"all"``: over every class 0..C-1, the reference
            DS-Net's ``calc_sem_label`` (to reproduce its published numbers with an imported
            checkpoint; 0.4–0.7 % of points differ with random weights).
        match: a transform of each cloud toward the training sensor
            (:class:`~dsnet_core.model.sensor_match.SensorMatch`) applied before the network reads
            it; None reads the clouds as given. Results stay per point of the given cloud.
    """

    def __init__(
        self,
        model: DSNet,
        card: ModelCard | None = None,
        device: str = "cpu",
        threads: int | None = 1,
        tta: TTAConfig | None = None,
        argmax: str = "labelled",
        match: Callable[[np.ndarray], np.ndarray] | None = None,
    ):
        if argmax not in ARGMAX_RULES:
            raise ValueError(f"argmax must be one of {ARGMAX_RULES}, got {argmax!r}")
        self.argmax = argmax
        if threads is not None and torch.device(device).type == "cpu":
            torch.set_num_threads(threads)
        self.device = torch.device(device)
        self.model = model.to(self.device).eval()
        self.card = card
        self.tta = tta or TTAConfig()
        self.match = match

    @classmethod
    def from_checkpoint(
        cls,
        path: str | Path,
        device: str = "cpu",
        threads: int | None = 1,
        expect_label_map: LabelMap | None = None,
        tta: TTAConfig | None = None,
        argmax: str = "labelled",
        match: str = "auto",
    ) -> Predictor:
        """Load a checkpoint folder (verified, see :func:`load_checkpoint`); ``match`` (one of
        :data:`~dsnet_core.model.sensor_match.MATCH_MODES`) toward its card's sensor reference.

        Raises:
            ConfigError: ``match`` asked of a card that records no sensor reference.
        """
        model, card = load_checkpoint(path, device=device, expect_label_map=expect_label_map)
        transform = sensor_match(path, card, match)
        return cls(model, card, device=device, threads=threads, tta=tta, argmax=argmax, match=transform)

    @property
    def num_classes(self) -> int:
        return self.model.config.num_classes

    def predict(self, points: np.ndarray) -> InferenceResult:
        """One cloud: float32 ``(N, 4)`` (x, y, z metres, remission) → :class:`InferenceResult`.

        A 4D volume is passed the same way (aligned scans concatenated); split the result back by
        the volume's per-point source-frame index.
        """
        return self.predict_batch([points])[0]

    def predict_batch(self, clouds: list[np.ndarray]) -> list[InferenceResult]:
        """Several clouds in one forward pass (batch index per cloud; no cross-talk)."""
        results: list[InferenceResult] = []
        for n, out, sl, probs, sem in self._forward(clouds):
            if n == 0:
                results.append(self._empty())
                continue
            # float16 conversions in torch: numpy's are scalar loops, ~0.1 s per 120k × 32 array
            results.append(
                InferenceResult(
                    sem=sem.cpu().numpy().astype(np.int64),
                    probs=probs.cpu().numpy(),
                    offsets=out.offsets[sl].float().cpu().numpy(),
                    features=out.features[sl].to(torch.float16).cpu().numpy(),
                )
            )
        return results

    def predict_stored(self, clouds: list[np.ndarray], keep: np.ndarray) -> list[StoredResult]:
        """:meth:`predict_batch` as the ``infer`` stage stores it: probabilities quantised
        (:func:`quantise`, once per voxel where every point takes its voxel's), offsets and features
        on the points whose class ``keep`` (bool ``(C,)``) marks, zero elsewhere. The same values as
        quantising and masking :meth:`predict_batch`'s results, with less work."""
        results: list[StoredResult] = []
        for n, out, sl, probs, sem in self._forward(clouds, quantised=True):
            if n == 0:
                e = self._empty()
                probs_q = e.probs.astype(np.uint8)
                results.append(StoredResult(e.sem, probs_q, e.offsets, e.features, np.zeros(0, bool)))
                continue
            sem_np = sem.cpu().numpy().astype(np.int64)
            kept = keep[sem_np]
            rows = torch.from_numpy(np.flatnonzero(kept)).to(self.device)
            offsets = np.zeros((n, 3), np.float32)
            features = np.zeros((n, out.features.shape[1]), np.float16)
            offsets[kept] = out.offsets[sl].index_select(0, rows).float().cpu().numpy()
            features[kept] = out.features[sl].index_select(0, rows).to(torch.float16).cpu().numpy()
            results.append(StoredResult(sem_np, probs.cpu().numpy(), offsets, features, kept))
        return results

    def _forward(self, clouds: list[np.ndarray], quantised: bool = False):
        """One forward pass over ``clouds``; per cloud ``(n, out, rows of out, probs, sem)``: float16
        probabilities (uint8 :func:`quantise` ones with ``quantised``) and classes per point."""
        tensors = []
        for i, pts in enumerate(clouds):
            arr = np.asarray(pts)
            if arr.ndim != 2 or arr.shape[1] < 4 or not np.isfinite(arr[:, :4]).all():
                raise DataFormatError(
                    f"<cloud {i}>", f"expected finite float (N, 4) points, got shape {arr.shape}"
                )
            if self.match is not None and arr.shape[0] > 0:
                arr = self.match(arr)
            tensors.append(torch.as_tensor(arr[:, :4], dtype=torch.float32, device=self.device))
        nonempty = [t for t in tensors if t.shape[0] > 0]
        with torch.inference_mode():
            out = tta_forward(self.model, nonempty, self.tta) if nonempty else None
        per_voxel = None
        if out is not None and self.tta.is_identity and out.voxel_logits is not None:
            # every point takes its voxel's logits: softmax and argmax once per voxel (~3x fewer rows)
            vlogits = out.voxel_logits.float()
            vprobs = torch.softmax(vlogits, dim=1).to(torch.float16)
            per_voxel = (quantise(vprobs) if quantised else vprobs, self._classes(vlogits))
        start = 0
        for t in tensors:
            n = t.shape[0]
            if n == 0:
                yield 0, None, None, None, None
                continue
            sl = slice(start, start + n)
            start += n
            if per_voxel is not None:
                vox = out.point_to_voxel[sl]
                probs, sem = (v.index_select(0, vox) for v in per_voxel)
            else:
                logits = out.logits[sl].float()
                probs = torch.softmax(logits, dim=1).to(torch.float16)
                probs = quantise(probs) if quantised else probs
                sem = self._classes(logits)
            yield n, out, sl, probs, sem

    def _classes(self, logits: torch.Tensor) -> torch.Tensor:
        """int64 ``(M,)`` class per row of float ``(M, C)`` logits, by :attr:`argmax`'s rule."""
        if self.argmax == "all":
            return logits.argmax(dim=1)
        return logits[:, 1:].argmax(dim=1) + 1

    def predict_stored_iter(
        self, clouds: Iterable[np.ndarray], keep: np.ndarray, batch_size: int = 1
    ) -> Iterator[StoredResult]:
        """Stream :meth:`predict_stored` results, ``batch_size`` clouds per forward pass."""
        buf: list[np.ndarray] = []
        for pts in clouds:
            buf.append(pts)
            if len(buf) == batch_size:
                yield from self.predict_stored(buf, keep)
                buf = []
        if buf:
            yield from self.predict_stored(buf, keep)

    def _empty(self) -> InferenceResult:
        c, d = self.num_classes, self.model.config.ins_dim
        return InferenceResult(
            sem=np.zeros(0, np.int64),
            probs=np.zeros((0, c), np.float16),
            offsets=np.zeros((0, 3), np.float32),
            features=np.zeros((0, d), np.float16),
        )
