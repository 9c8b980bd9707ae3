"""Bulk generation: many prompts into a sharded Parquet dataset, over the workers of a Ray cluster
(`smf bulk`, docs/bulk.md). :mod:`.dataset` plans the shards and reads and writes them (no Ray);
:mod:`.ray_run` runs the plan on Ray."""
