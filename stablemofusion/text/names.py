"""The text-side files a model folder may hold beside its motion weights (no torch: the portable runtime reads
these names too). A teacher shipped inside its student's folder uses the student's
(:func:`stablemofusion.diffusion.checkpoint.companion_file`)."""

ACTIONS_FILE = "actions.json"  # the known actions and their example sentences (text.known)
EMBEDDINGS_FILE = "actions.safetensors"  # their sentence embeddings (in a model with graphs: GRAPHS_DIR/actions.npy)
GRAPHS_DIR = "onnx"  # inside a model folder: its portable graphs (smf export --onnx)
DETECTOR_FILE = "ood.safetensors"  # the out-of-domain detector (text.domain)
LENGTH_WEIGHTS, LENGTH_CONFIG = "length.safetensors", "length.json"  # the length estimator (text.length)
TEXT_SIDE_FILES = (LENGTH_CONFIG, LENGTH_WEIGHTS, ACTIONS_FILE, EMBEDDINGS_FILE, DETECTOR_FILE)
