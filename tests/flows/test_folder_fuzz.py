"""Fuzzing the model folders of ``train``, ``adapt`` and ``import-checkpoint``: every file of a
finished folder truncated, bit-flipped or deleted, then ``--resume``, ``label --checkpoint`` and
``import-checkpoint`` over it: a typed one-line refusal naming the file, or exactly the undamaged
folder's result — never a traceback, never a silent mix (see :mod:`tests.flows.folder_fuzz`).

``DSNET_FUZZ_SEEDS`` (default 1) cases per file, damage and command; ``DSNET_FUZZ_KINDS`` (comma
separated: train, train1, adapt, import) limits the folders."""

from __future__ import annotations

import os

import pytest

from tests.flows import folder_fuzz as fuzz


@pytest.mark.slow
@pytest.mark.timeout(3600)
def test_fuzz_model_folders(tmp_path_factory):
    seeds = int(os.environ.get("DSNET_FUZZ_SEEDS", "1"))
    kinds = [k for k in os.environ.get("DSNET_FUZZ_KINDS", ",".join(fuzz.KINDS)).split(",") if k]
    base = tmp_path_factory.mktemp("folder-fuzz")
    ref = fuzz.build_reference(base)
    cases = []
    for kind in kinds:
        for file in fuzz.folder_files(ref.folders[kind]):
            for how in fuzz.DAMAGES:
                for command in ("resume", "label", "import"):
                    for seed in range(seeds):
                        cases.append(fuzz.run_case(ref, kind, file, how, command, seed, base / "work"))
    table = fuzz.summarise(cases)
    (base / "table.txt").write_text(table + "\n")
    print(f"\n{table}\n(table under {base})")
    assert not [c for c in cases if c.outcome in fuzz.FAILURES], table
