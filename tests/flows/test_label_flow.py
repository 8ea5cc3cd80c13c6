"""label-dataset on a 2-sequence log through a real Prefect server: run, no-op rerun, --scans change
(ingest and align only; the model stages are tested in test_label_model_flow)."""

import numpy as np
import pytest

from storage.run import RunStore
from tasks.methods import get_pipeline
from tests.helpers.label_request import req
from tests.logs import make_log

P = get_pipeline()  # the DS-Net stages


@pytest.fixture(scope="module")
def two_seq_log(tmp_path_factory):
    return make_log(tmp_path_factory.mktemp("log"), ("00", "01"), n_frames=6)


def _actions(summary):
    return {(r["sequence"], r["stage"]): r["action"] for r in summary}


def test_label_dataset_resumes_exactly(prefect_api_url, two_seq_log, tmp_path):
    from flows.label import label_dataset

    root = str(tmp_path / "run")
    opts = {"block_size": 2}
    first = label_dataset(req(str(two_seq_log), root, None, {"align": {"scans": 2}}, opts, until="align"))
    assert _actions(first) == {(s, st): "fresh" for s in ("00", "01") for st in ("ingest", "align")}
    store = RunStore(root)
    fps = {
        (s, st): store.read_manifest(s, st).fingerprint for s in ("00", "01") for st in ("ingest", "align")
    }
    arrays = store.arrays("01", P["align"].contract)
    assert arrays.done().all() and arrays.n_items == 5  # windows of 2 with stride 1 over 6 frames

    again = label_dataset(req(str(two_seq_log), root, None, {"align": {"scans": 2}}, opts, until="align"))
    assert set(_actions(again).values()) == {"skip"} and all(r["blocks_run"] == 0 for r in again)

    third = label_dataset(
        req(str(two_seq_log), root, ["00", "01"], {"align": {"scans": 3}}, opts, until="align")
    )
    acts = _actions(third)
    assert acts[("00", "ingest")] == acts[("01", "ingest")] == "skip"
    assert acts[("00", "align")] == acts[("01", "align")] == "fresh"
    assert store.read_manifest("00", "ingest").fingerprint == fps[("00", "ingest")]
    assert store.read_manifest("00", "align").fingerprint != fps[("00", "align")]
    assert store.read_manifest("00", "align").plan["windows"] == [[0, 1, 2], [2, 3, 4], [3, 4, 5]]

    forced = label_dataset(
        req(str(two_seq_log), root, ["00"], {"align": {"scans": 3}}, opts, from_stage="align", until="align")
    )
    assert _actions(forced) == {("00", "ingest"): "skip", ("00", "align"): "fresh"}
    vol = store.arrays("00", P["align"].contract).read_item(0)
    assert set(np.unique(vol["source_frame"])) == {0, 1, 2}


def test_label_sequence_and_artifacts(prefect_api_url, two_seq_log, tmp_path):
    from prefect.client.orchestration import get_client
    from prefect.client.schemas.filters import ArtifactFilter, ArtifactFilterKey
    from prefect.client.schemas.sorting import ArtifactSort

    from flows.label import label_sequence

    summary = label_sequence(req(str(two_seq_log), str(tmp_path / "run"), until="align"), "01")
    assert _actions(summary) == {("01", "ingest"): "fresh", ("01", "align"): "fresh"}
    with get_client(sync_client=True) as client:
        for key, kind in (
            ("label-summary", "table"),
            ("label-report", "markdown"),
            ("label-progress", "progress"),
        ):
            flt = ArtifactFilter(key=ArtifactFilterKey(any_=[key]))
            arts = client.read_artifacts(artifact_filter=flt, sort=ArtifactSort.CREATED_DESC, limit=1)
            assert arts and arts[0].type == kind
    assert arts[0].data == 100.0  # the latest progress artifact: this run's, complete


def test_s3_store_resumes(prefect_api_url, s3_endpoint, two_seq_log):
    import uuid

    from flows.label import label_dataset
    from storage.tables import read_table
    from tasks.align import VOLUMES

    root = f"s3://dsnet-test/flow-{uuid.uuid4().hex[:8]}"
    args = (str(two_seq_log), root, ["00"], {"align": {"scans": 2}}, {"block_size": 2})
    assert set(_actions(label_dataset(req(*args, until="align"))).values()) == {"fresh"}
    store = RunStore(root)
    ref = store.arrays("00", P["align"].contract)
    ref = {name: ref.group[name][:] for name in (*ref.names, "n_points", "done")}
    # the state a kill in the middle of align leaves: a block missing, manifest running, a temp object
    base = store.stage_rel("00", "align")
    store.root.remove(f"{base}/blocks/00001.json")
    m = store.read_manifest("00", "align")
    m.status = "running"
    store.write_manifest(m)
    store.root.write_bytes("tables/volumes/sequence=00/.part-0.parquet.dead.tmp", b"junk")
    second = label_dataset(req(*args, until="align"))
    assert {(r["stage"], r["action"], r["blocks_run"]) for r in second} == {
        ("ingest", "skip", 0),
        ("align", "resume", 1),
    }
    got = store.arrays("00", P["align"].contract)
    assert all(np.array_equal(got.group[name][:], ref[name]) for name in ref)
    assert (
        read_table(store.root, VOLUMES)["sequence"].to_pylist() == ["00"] * 5
    )  # the temp object is not data


def test_retries_only_transient_storage_errors():
    from prefect.states import Failed

    from dsnet_core.errors import ScanFormatError
    from flows.stage_loop import _transient
    from storage.errors import LockLostError

    def retried(exc):
        return _transient(None, None, Failed(data=exc))

    assert retried(OSError("connection reset")) and retried(TimeoutError()) and retried(ConnectionError())
    assert not retried(ScanFormatError("a.bin", "truncated"))
    assert not retried(LockLostError("lock.json", "taken over"))
    assert not retried(FileNotFoundError("gone")) and not retried(ValueError("bug"))
