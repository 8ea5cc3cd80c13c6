"""Record the sensor reference (``training_data.sensor_reference``) of bundled stream-trained models.

``dsnet train`` writes the reference into every new card; models bundled before it existed get it
here, from the same scans their trainer probed its class counts on: the card's stream record
(seed, frames, styles, sensors) and its probe frames (``training_data.frames``) re-rendered.

Run: ``.venv/bin/python bench/sensor_reference.py dsnet_core/data/models/tiny-v2 [...]``
(rewrites each card; the weights and their sha256 are untouched).
"""

from __future__ import annotations

import sys

from dsnet_core.model.checkpoint import read_card, write_card
from dsnet_core.train.data import probe_statistics
from dsnet_core.train.finetune import volume_name
from dsnet_core.train.stream import StreamLog, StreamOptions


def main(paths: list[str]) -> None:
    for path in paths:
        card = read_card(path)
        data = dict(card.training_data)
        rec = data.get("stream")
        if not rec:
            print(f"{path}: not trained on a stream: left as it is")
            continue
        options = StreamOptions(
            frames=int(rec["frames"]),
            styles=None if rec["styles"] == "all" else tuple(rec["styles"]),
            sensors=None if rec["sensors"] == "all" else tuple(rec["sensors"]),
        )
        log = StreamLog(int(rec["seed"]), options, int(rec["samples_per_epoch"]))
        names = log.probe()
        if [volume_name(v) for v in log.volumes(names)] != data["frames"]:
            raise SystemExit(f"{path}: its probe frames are not the stream's probe window")
        data["sensor_reference"] = probe_statistics(log, log.volumes(names), log.label_map)[1]
        card.training_data = data
        write_card(path, card)
        ref = data["sensor_reference"]
        print(f"{path}: ground {ref['ground']} m, remission median {ref['remission_quantiles'][50]}")


if __name__ == "__main__":
    main(sys.argv[1:])
