"""The defaults and limits of a generation request, one table for every door: the library, `smf`, the HTTP API and
the viewer (which sends its requests to the HTTP API and shows its answers). A value outside a limit is refused
with one line naming it (``SMFError``; the command line exits 2, HTTP answers 422), never clamped silently.

Pure Python (no numpy, no torch): the command line's parsers read it without loading the model code.
"""

from __future__ import annotations

import math
import numbers
import random

from .errors import SMFError

# --- defaults ---
# classifier-free guidance scale of a model whose config names none (a model's own: its config's ``guidance``, set
# by `smf export --guidance`; a distilled student takes the scale as an input)
GUIDANCE = 2.5
STEPS = 10  # sampling steps of an ordinary model (a distilled student: its checkpoint's distil.sample_steps)
SAMPLER = "sde-dpmsolver++-karras"  # sampler of an ordinary model
STUDENT_SAMPLER = "lcm"  # sampler of a distilled student (multistep consistency sampling)
# steps of a distilled student when it edits a motion (at least; its own count if larger): at 1 step the kept frames
# are imposed on its only prediction, which never saw them, and the seams were twice the teacher's (docs/editing.md)
STUDENT_EDIT_STEPS = 4
# the most steps a distilled student samples soundly (a model's config may name its own: ``max_steps``): past them
# its multistep consistency sampling drifts. The shipped 1-step student, 6 prompts x 4 s, the root's largest speed:
# 2.6 m/s at 1-6 steps, 3.6 at 7, 5.1 at 8, 9.2 at 10, 80 at 20, 6e5 at 50 (its joints 470 km away)
STUDENT_MAX_STEPS = 6
BATCH_SIZE = 32  # prompts per sampling call
DEFAULT_SECONDS = 4.0  # length of a motion when none is given and the model has no length estimator
FOOTSKATE_MODES = ("off", "post", "loop")
PORTABLE_FOOTSKATE = ("off", "post")  # what the portable runtime runs: 'loop' runs inside the torch sampler
# footskate cleanup of a generated motion unless a request says otherwise (the rigid stage on): measured on the shipped
# 1-step student, 96 test captions x 2 seeds, `benchmarks/final_stage_check.py quality` (2-core AMD EPYC): the raw
# motion's skate ratio is 0.213 against 0.070 for the real clips of those captions; after 'post' 0.049 and no foot
# ever jumps, for about 3-4 ms more per motion. docs/footskate.md.
FOOTSKATE = "post"
PORTABLE_ENGINE = "onnx"  # the command line's engine that means the ONNX backend (stablemofusion.backends), no torch
ENGINES = ("eager", "fast", "compiled", "graph", "compiled-graph", "aot")  # diffusion/engine.py: what each does
OUTPUT_FORMATS = ("npy", "json", "bvh", "glb", "mp4", "gif")  # output.py: one writer each
DEFAULT_FORMATS = "npy,bvh,glb"  # no rendering: mp4 needs the [video] extra, gif and mp4 take about 1 s
EDIT_MODES = ("prefix", "suffix", "inbetween", "upper-body", "lower-body", "trajectory")  # edit.py: what each keeps
IMPOSE = ("x0", "xt")  # where an edit imposes the kept part: the x0 prediction or the noisy sample

# --- limits ---
MAX_SECONDS = 120.0  # a motion or a whole timeline; longer than the model's window: made window by window
# motion files read at any door (the command line, the library, HTTP uploads): checked before anything is resampled
MIN_FRAME_TIME_S = 1e-3  # a BVH between 1 and 1000 frames per second
MAX_FRAME_TIME_S = 1.0
MAX_ABS_VALUE = 1e6  # any number of a motion file (metres, centimetres, millimetres or degrees)
MIN_STEPS, MAX_STEPS = 1, 50
MIN_GUIDANCE, MAX_GUIDANCE = 0.0, 20.0
MAX_SEGMENTS = 16  # segments of a timeline
MAX_PROMPT_CHARS = 300
MAX_BATCH_SIZE = 256
LENGTH_MULTIPLE = 4  # generated lengths are whole multiples of this many frames (pipelines, distillation)
SEED_RANGE = 2**53  # seeds are whole numbers in [0, SEED_RANGE): exact in JavaScript too (the viewer sends them back)
FRESH_SEEDS = 2**32  # a request without a seed gets one drawn from [0, FRESH_SEEDS): short enough to type again


def _whole(x) -> bool:
    return isinstance(x, numbers.Integral) and not isinstance(x, bool)


def _number(x) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x)


def check_steps(steps: int | None) -> int | None:
    """Sampling steps in [MIN_STEPS, MAX_STEPS], or None (the model's own)."""
    if steps is not None and (not _whole(steps) or not MIN_STEPS <= steps <= MAX_STEPS):
        raise SMFError(f"steps must be a whole number from {MIN_STEPS} to {MAX_STEPS}, got {steps}")
    return steps


def check_guidance(scale: float | None) -> float | None:
    """A guidance scale in [MIN_GUIDANCE, MAX_GUIDANCE], or None (the model's own)."""
    if scale is not None and (not _number(scale) or not MIN_GUIDANCE <= scale <= MAX_GUIDANCE):
        raise SMFError(f"guidance must be a number from {MIN_GUIDANCE:g} to {MAX_GUIDANCE:g}, got {scale}")
    return scale


def check_seconds(seconds: float | None, what: str = "seconds") -> float | None:
    """A positive length of at most MAX_SECONDS (a motion, or a timeline's total), or None (predicted)."""
    if seconds is not None and (not _number(seconds) or not 0 < seconds <= MAX_SECONDS):
        raise SMFError(f"{what} must be more than 0 and at most {MAX_SECONDS:g} s, got {seconds}")
    return seconds


def check_segments(count: int) -> int:
    if not 1 <= count <= MAX_SEGMENTS:
        raise SMFError(f"a timeline has 1 to {MAX_SEGMENTS} segments, got {count}")
    return count


def check_seed(seed: int | None) -> int | None:
    """A seed in [0, SEED_RANGE), or None (a fresh one)."""
    if seed is not None and (not _whole(seed) or not 0 <= seed < SEED_RANGE):
        raise SMFError(f"seed must be a whole number from 0 to {SEED_RANGE - 1}, got {seed}")
    return seed


def check_batch_size(n: int) -> int:
    if not _whole(n) or not 1 <= n <= MAX_BATCH_SIZE:
        raise SMFError(f"batch size must be a whole number from 1 to {MAX_BATCH_SIZE}, got {n}")
    return n


def check_footskate(mode: str) -> str:
    if mode not in FOOTSKATE_MODES:
        raise SMFError(f"footskate must be one of {', '.join(FOOTSKATE_MODES)}, got {mode!r}")
    return mode


def check_prompt(text, what: str = "the prompt") -> str:
    """A prompt of 1 to MAX_PROMPT_CHARS characters (surrounding spaces not counted), returned stripped."""
    if not isinstance(text, str) or not text.strip():
        raise SMFError(f"{what} must be a non-empty text")
    text = text.strip()
    if len(text) > MAX_PROMPT_CHARS:
        raise SMFError(f"{what} must have at most {MAX_PROMPT_CHARS} characters, got {len(text)}")
    return text


# the work of a request in step-equivalents per second of motion: each sampling step costs one per pass (two with
# classifier-free guidance), footskate 'post' about CLEANUP_STEPS more, 'loop' that once more per cleaned step
# (the shipped student, one thread, 2-core AMD EPYC: a 120 s timeline at 1 step with 'post' 1.3 s, at 6 steps
# 2.5 s; with 'loop' 2.6 and 5.9 s)
CLEANUP_STEPS = 5
LOOP_CLEANED_STEPS = 2  # footskate.FootskateOptions.loop_steps


def request_cost(seconds: float, steps: int, guided: bool, footskate: str) -> float:
    """A request's work before it runs, in step-seconds: ``seconds`` of motion (a timeline's total) sampled with
    ``steps`` steps (two passes each when ``guided``), plus its footskate cleanup."""
    cleanup = {"off": 0, "post": CLEANUP_STEPS, "loop": CLEANUP_STEPS * (1 + LOOP_CLEANED_STEPS)}[footskate]
    return seconds * (steps * (2 if guided else 1) + cleanup)


def fresh_seed() -> int:
    """A random seed for a request without one (reported with its result, so the motion can be made again)."""
    return random.randrange(FRESH_SEEDS)


def base_seed(seed: int | None) -> int:
    """The seed policy of every door: a request's seed as given (checked), or a fresh one."""
    return fresh_seed() if check_seed(seed) is None else int(seed)


def table() -> dict:
    """The limits as JSON (GET /v1/health, the viewer)."""
    return {"seconds": [0, MAX_SECONDS], "steps": [MIN_STEPS, MAX_STEPS], "guidance": [MIN_GUIDANCE, MAX_GUIDANCE],
            "segments": MAX_SEGMENTS, "prompt_chars": MAX_PROMPT_CHARS, "seed": [0, SEED_RANGE - 1],
            "footskate": list(FOOTSKATE_MODES)}
