"""The text side of a model: the frozen text encoder and its embedding caches, the length-from-text estimator,
and the known actions with their out-of-domain detector."""

from .domain import DETECTOR_FILE
from .known import ACTIONS_FILE, EMBEDDINGS_FILE
from .length import CONFIG as LENGTH_CONFIG
from .length import WEIGHTS as LENGTH_WEIGHTS

# the text-side files a model folder may hold beside its motion weights; a teacher shipped inside its student's
# folder uses the student's (diffusion.checkpoint.companion_file)
TEXT_SIDE_FILES = (LENGTH_CONFIG, LENGTH_WEIGHTS, ACTIONS_FILE, EMBEDDINGS_FILE, DETECTOR_FILE)
