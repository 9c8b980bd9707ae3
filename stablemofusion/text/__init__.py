"""The text side of a model: the frozen text encoder and its embedding caches, the length-from-text estimator,
and the known actions with their out-of-domain detector."""

from .names import (ACTIONS_FILE, DETECTOR_FILE, EMBEDDINGS_FILE, LENGTH_CONFIG, LENGTH_WEIGHTS,  # noqa: F401
                    TEXT_SIDE_FILES)
