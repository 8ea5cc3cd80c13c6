"""The training stream rendered with a sensor card (``dsnet train dsnet --stream --stream-like LOG``)."""

import numpy as np

from dsnet_core.sensor import parse_card
from dsnet_core.synth import generate_log
from dsnet_core.synth.stream import StreamOptions, stream_sample
from tests.dsnet_core.sensor.test_card import _card


def test_stream_samples_have_the_cards_beams_and_fov():
    card = parse_card(_card())
    plain = stream_sample(0, 0, StreamOptions(frames=1))
    sample = stream_sample(0, 0, StreamOptions(frames=1, card=card))
    assert sample.setup["sensor"] == "card:tiny" and sample.setup["style"] == plain.setup["style"]
    scan = sample.scans[0]
    el = np.degrees(np.arctan2(scan[:, 2], np.hypot(scan[:, 0], scan[:, 1])))
    assert np.abs(el[:, None] - np.array(card.elevations_deg)[None]).min(axis=1).max() < 1e-3
    az = np.degrees(np.arctan2(scan[:, 1], scan[:, 0]))
    assert np.abs(az).max() <= 45.0 and 0 < scan.shape[0] <= 270
    assert np.array_equal(stream_sample(0, 0, StreamOptions(frames=1, card=card)).scans[0], scan)


def test_stream_like_estimates_the_card_and_records_it(tmp_path):
    from tasks.methods.dsnet_train import DsnetTrainOptions, stream_reader

    generate_log(tmp_path, sequences=1, frames=1, seed=0, sensor="vlp16")
    options = DsnetTrainOptions(
        out=str(tmp_path / "m"), stream=2, stream_like=str(tmp_path), val_data=str(tmp_path)
    )
    log = stream_reader(options)
    assert log.options.card.beams == 16
    assert log.record()["sensor_card"]["beams"] == 16
    plain = stream_reader(DsnetTrainOptions(out=str(tmp_path / "m"), stream=2, val_data=str(tmp_path)))
    assert "sensor_card" not in plain.record() and plain.fingerprint() != log.fingerprint()
