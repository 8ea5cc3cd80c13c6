"""The settings of offline refinement, as plain frozen dataclasses (the stage's pydantic config
turns into these; the algorithms never see a config object).

Units: metres, frames (frame indices of the sequence), shares in [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class VoteParams:
    """Static-world voting.

    Attributes:
        enabled: run the static vote at all (the track steps run regardless).
        voxel: edge of the world voxels the votes are hashed into, metres.
        window: W: a frame's vote gathers the frames whose index is within ±W of its own
            (the whole sequence when it is shorter than 2W + 1 frames).
        min_frames: a voxel's consensus needs votes from at least this many frames of the window.
        min_share: ... and its winning class at least this share of the voxel's weighted votes.
        min_votes: ... and at least this many full-weight point votes in total.
        range_ref: points nearer than this (metres) vote with full weight, farther ones with
            weight ``range_ref / range`` (near returns are surer); None: every point weighs 1.
        top_k: classes kept per voxel and frame (the rest of a soft vote is dropped), >= 1.
    """

    enabled: bool = True
    voxel: float = 0.3
    window: int = 10
    min_frames: int = 3
    min_share: float = 0.6
    min_votes: float = 2.0
    range_ref: float | None = 20.0
    top_k: int = 3

    def __post_init__(self) -> None:
        if self.voxel <= 0 or self.window < 0 or self.min_frames < 1 or self.top_k < 1:
            raise ValueError(f"invalid vote settings {self}")
        if not 0.0 <= self.min_share <= 1.0 or self.min_votes < 0:
            raise ValueError(f"invalid vote settings {self}")
        if self.range_ref is not None and self.range_ref <= 0:
            raise ValueError(f"range_ref must be positive or None, got {self.range_ref}")


@dataclass(frozen=True)
class TrackParams:
    """One class per track, dissolving, motion and joining.

    Attributes:
        dissolve_frames: a track seen in at most this many frames may dissolve ...
        dissolve_confidence: ... when its confidence is below this and its vote says stuff (its
            stuff classes outweigh its thing classes).
        moving_distance: a track is moving when its (3-frame median) centre strays from where it
            started by more than this (metres) ...
        moving_extent: ... plus this share of its median horizontal extent (the centroid of a
            parked car drifts by up to half its length as the sensor sees other sides of it).
        min_static_frames: a track seen in fewer frames has an unknown motion and is treated as
            moving (it neither votes nor takes the static vote).
        join_gap: G: tracks are joined across at most this many frames without a sighting.
        join_distance: the largest mean distance (metres) between each track's position
            extrapolated over the gap and the other's observed centre.
        velocity_frames: sightings a track's end (start) velocity is fitted to.
        class_margin: a point of a thing class ``c`` keeps ``c`` instead of taking its track's
            class ``w`` (the winner of the track's vote) when the track's vote does not beat ``c``
            by this factor and the point's sighting (its instance in its frame) prefers ``c`` over
            ``w`` by it: a confident instance is re-labelled only by a clear track vote, an unsure
            one takes its track's class. 0: every point takes ``w`` (the bare plurality).
    """

    dissolve_frames: int = 3
    dissolve_confidence: float = 0.5
    moving_distance: float = 0.5
    moving_extent: float = 0.5
    min_static_frames: int = 2
    join_gap: int = 5
    join_distance: float = 1.0
    velocity_frames: int = 5
    class_margin: float = 2.0

    def __post_init__(self) -> None:
        if min(self.dissolve_frames, self.join_gap, self.min_static_frames) < 0 or self.velocity_frames < 1:
            raise ValueError(f"invalid track settings {self}")
        if not self.class_margin >= 0.0:
            raise ValueError(f"class_margin must be at least 0, got {self.class_margin}")
        if self.moving_distance < 0 or self.moving_extent < 0 or self.join_distance < 0:
            raise ValueError(f"invalid track settings {self}")


@dataclass(frozen=True)
class GroundParams:
    """The optional ground prior (a training-free ground segmentation of each scan).

    Attributes:
        enabled: correct points by the ground segmentation (needs per-point probabilities and
            a label map that declares its ground classes).
        max_confidence: only points whose probability of their class is below this are corrected.
        sensor_height: the sensor's height above the ground, metres (Patchwork++'s prior).
    """

    enabled: bool = False
    max_confidence: float = 0.6
    sensor_height: float = 1.73

    def __post_init__(self) -> None:
        if not 0.0 <= self.max_confidence <= 1.0 or self.sensor_height <= 0:
            raise ValueError(f"invalid ground settings {self}")


@dataclass(frozen=True)
class RefineParams:
    """Everything refinement needs besides the data."""

    vote: VoteParams = field(default_factory=VoteParams)
    track: TrackParams = field(default_factory=TrackParams)
    ground: GroundParams = field(default_factory=GroundParams)
