"""Batch reconstruction on Dask: a manifest of items (`manifest`), the SQLite job store
that makes a batch resumable (`store`), what a worker runs for one item (`work`) and
the client that drives a local or existing cluster (`run`). docs/batch.md."""
