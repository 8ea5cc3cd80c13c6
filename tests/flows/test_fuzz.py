"""Fuzzing a finished run's inputs and store: every truncated, bit-flipped or deleted scan, label,
pose, calibration, timestamp, checkpoint, manifest, block fragment, item record, zarr chunk or
metadata and parquet file ends in a typed one-line error naming the file, a quarantined frame,
a recomputation or a valid different input's labels — never a traceback, never a silently wrong
label (see :mod:`tests.flows.fuzz`).

``DSNET_FUZZ_SEEDS`` (default 2) cases per target and damage; ``DSNET_FUZZ_TARGETS`` (comma
separated) limits the targets."""

from __future__ import annotations

import os

import pytest

from tests.flows import fuzz


@pytest.mark.slow
def test_fuzz_inputs_and_store(prefect_api_url, tmp_path_factory):
    seeds = int(os.environ.get("DSNET_FUZZ_SEEDS", "2"))
    targets = [t for t in os.environ.get("DSNET_FUZZ_TARGETS", ",".join(fuzz.TARGETS)).split(",") if t]
    base = tmp_path_factory.mktemp("fuzz")
    ref = fuzz.build_reference(base)
    cases = []
    for target in targets:
        for kind in fuzz.DAMAGES:
            for seed in range(seeds):
                cases.append(fuzz.run_case(ref, target, kind, seed, keep=base / "failed"))
    table = fuzz.summarise(cases)
    (base / "table.txt").write_text(table + "\n")
    print(f"\n{table}\n(table and failing cases under {base})")
    failures = [c for c in cases if c.outcome in fuzz.FAILURES]
    assert not failures, table
