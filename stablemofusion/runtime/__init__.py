"""The portable runtime: the exported graphs (``smf export --onnx``) on ONNX Runtime and numpy, no torch."""
