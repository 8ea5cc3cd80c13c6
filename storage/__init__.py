"""The run store: zarr arrays, parquet tables, manifests, fsspec URLs. Knows nothing of Prefect."""
