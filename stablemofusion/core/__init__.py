"""The torch-free core: errors, limits, settings, seeded noise, plans (edits, paths, timelines, streams), the final
stage's entry points, the result type and model folders. Everything above it (backends, task pipelines, training
and evaluation, serving, the command line) may import it; it imports none of them (tests/test_layers.py)."""
