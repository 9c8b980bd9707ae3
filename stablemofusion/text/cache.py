"""Caches of frozen text-encoder outputs, so a caption already seen never goes through the language model again.

* :class:`TextEmbeddingCache`: on disk, for training. A folder holding
  ``index.json`` and one ``shard-*.safetensors`` per flush. A shard holds one float32 tensor ``tokens``
  (N, dim): the valid (unpadded) token rows of its captions laid end to end. The index maps
  ``sha1(encoder name, max_tokens, caption)`` to ``[shard number, first row, length]``. Shards are
  immutable and written atomically under a fresh name *before* the index (also written atomically) names
  them, so a reader, or a new cache object after a crash, only ever sees complete shards: a flush that
  fails leaves the previous state intact (at worst an unreferenced shard file is left behind).
  The index is read on first use and shards are opened lazily (memory-mapped, row ranges read on demand).
  Not safe for two writers at once: the last flush wins each index entry it writes, and a flush merges
  with the index on disk, so entries another process flushed in between are kept.
* :class:`LRUTextCache`: in memory, least-recently-used, for inference (``maxsize`` captions).

Both have ``get_or_compute(texts) -> (tokens (B, L, dim) float32, mask (B, L) bool)``, equal to
``encoder.encode(texts)`` (padded to the longest caption, zero padding), running the encoder only on the
captions not cached, in batches of ``batch_size``; ``hits`` / ``misses`` count requested captions and
``encoder_calls`` counts ``encode`` batches.
"""

from __future__ import annotations

import hashlib
import json
import os
import secrets
import time
from collections import OrderedDict
from pathlib import Path
from typing import Any, Iterable

import torch

from ..core.errors import SMFError
from ..core.io import atomic_path, write_text
from .frozen import MAX_TOKENS, FrozenTextEncoder, load_text_encoder

INDEX_NAME = "index.json"
INDEX_VERSION = 1


def caption_key(encoder_name: str, max_tokens: int, caption: str) -> str:
    """The cache key of ``caption`` under an encoder: sha1 hex of name, token limit and caption."""
    return hashlib.sha1(f"{encoder_name}\x00{int(max_tokens)}\x00{caption}".encode("utf-8")).hexdigest()


def pad_rows(rows: list[torch.Tensor], dim: int, device: torch.device | str | None = None
             ) -> tuple[torch.Tensor, torch.Tensor]:
    """Valid-token rows [(L_i, dim)] -> (tokens (B, max L_i, dim) zero-padded float32, mask (B, max L_i))."""
    B = len(rows)
    L = max((r.shape[0] for r in rows), default=0)
    if device is None:
        device = rows[0].device if rows else "cpu"
    tokens = torch.zeros(B, L, dim, dtype=torch.float32, device=device)
    mask = torch.zeros(B, L, dtype=torch.bool, device=device)
    for i, r in enumerate(rows):
        n = r.shape[0]
        tokens[i, :n] = r.to(device=device, dtype=torch.float32)
        mask[i, :n] = True
    return tokens, mask


class _EncoderCache:
    """The shared ``get_or_compute`` logic; subclasses provide ``_lookup`` / ``_store`` / ``_key``."""

    def __init__(self, batch_size: int = 64):
        if batch_size < 1:
            raise ValueError("batch_size must be at least 1")
        self.batch_size = int(batch_size)
        self.hits = 0
        self.misses = 0
        self.encoder_calls = 0

    # -- provided by subclasses --------------------------------------------------------------------------
    def _key(self, text: str) -> str:
        raise NotImplementedError

    def _lookup(self, key: str) -> torch.Tensor | None:
        raise NotImplementedError

    def _store(self, key: str, rows: torch.Tensor) -> None:
        raise NotImplementedError

    def _encoder(self) -> FrozenTextEncoder:
        raise NotImplementedError

    def _dim(self) -> int:
        return self._encoder().dim

    def _after_compute(self) -> None:
        pass

    # -- shared ------------------------------------------------------------------------------------------
    def _compute(self, texts: list[str], keys: list[str]) -> dict[str, torch.Tensor]:
        """Encode ``texts`` in batches; store and return their valid rows by key."""
        encoder = self._encoder()
        out: dict[str, torch.Tensor] = {}
        for start in range(0, len(texts), self.batch_size):
            chunk = texts[start:start + self.batch_size]
            tokens, mask = encoder.encode(chunk)
            self.encoder_calls += 1
            for i, key in enumerate(keys[start:start + self.batch_size]):
                rows = tokens[i][mask[i]]
                out[key] = rows
                self._store(key, rows)
        return out

    def get_or_compute(self, texts: list[str], device: torch.device | str | None = None
                       ) -> tuple[torch.Tensor, torch.Tensor]:
        """Captions -> (tokens (B, L, dim) float32, mask (B, L) bool), encoding only the uncached ones.

        ``device`` defaults to where the cache keeps its rows (CPU for the disk cache, the encoder's device
        for the LRU cache).
        """
        if isinstance(texts, str):
            raise TypeError("get_or_compute takes a list of captions, not a single string")
        texts = [str(t) for t in texts]
        keys = [self._key(t) for t in texts]
        found: dict[str, torch.Tensor] = {}
        todo: dict[str, str] = {}  # key -> caption, first-seen order, each once
        for text, key in zip(texts, keys):
            if key in found or key in todo:
                if key in found:
                    self.hits += 1
                else:
                    self.misses += 1
                continue
            rows = self._lookup(key)
            if rows is None:
                todo[key] = text
                self.misses += 1
            else:
                found[key] = rows
                self.hits += 1
        if todo:
            found.update(self._compute(list(todo.values()), list(todo.keys())))
            self._after_compute()
        return pad_rows([found[k] for k in keys], self._dim(), device)

    def precompute(self, texts: Iterable[str]) -> int:
        """Encode every caption of ``texts`` not cached yet (sorted by length, to batch similar lengths).

        Returns how many were encoded.
        """
        todo: dict[str, str] = {}
        for text in texts:
            text = str(text)
            key = self._key(text)
            if key not in todo and self._lookup(key) is None:
                todo[key] = text
        order = sorted(todo, key=lambda k: len(todo[k]))
        if order:
            self._compute([todo[k] for k in order], order)
            self._after_compute()
        return len(order)


class TextEmbeddingCache(_EncoderCache):
    """On-disk cache of a frozen encoder's token embeddings (see the module docstring for the layout).

    ``encoder`` is a :class:`FrozenTextEncoder` or its name (``"minilm"``, ``"clip:<folder>"``); with a
    name the language model is only loaded on the first caption missing from the cache. New rows are kept
    in memory (and served from there) until ``flush_every`` captions are pending, or :meth:`flush` /
    :meth:`close` is called (also on leaving a ``with`` block).
    """

    def __init__(self, folder: str | os.PathLike, encoder: FrozenTextEncoder | str, batch_size: int = 64,
                 flush_every: int = 1024):
        super().__init__(batch_size)
        self.folder = Path(folder)
        if isinstance(encoder, str):
            self._enc: FrozenTextEncoder | None = None
            self._enc_name = encoder
            self._max_tokens = MAX_TOKENS
        else:
            self._enc = encoder
            self._enc_name = encoder.name
            self._max_tokens = encoder.max_tokens
        self.flush_every = int(flush_every)
        self._index: dict[str, Any] | None = None  # read lazily
        self._pending: dict[str, torch.Tensor] = {}
        self._handles: dict[str, Any] = {}

    @property
    def encoder_name(self) -> str:
        return self._enc_name

    @property
    def index_path(self) -> Path:
        return self.folder / INDEX_NAME

    # -- index and shards --------------------------------------------------------------------------------
    def _read_index(self) -> dict[str, Any]:
        path = self.index_path
        if not path.exists():
            return {"version": INDEX_VERSION, "shards": [], "dims": {}, "entries": {}}
        try:
            index = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as e:
            raise SMFError(f"text embedding cache index {path} is unreadable: {e}") from e
        if not isinstance(index, dict) or index.get("version") != INDEX_VERSION:
            raise SMFError(f"text embedding cache index {path} has an unknown format (version "
                           f"{index.get('version') if isinstance(index, dict) else '?'}, expected {INDEX_VERSION})")
        return index

    @property
    def index(self) -> dict[str, Any]:
        if self._index is None:
            self._index = self._read_index()
        return self._index

    def refresh(self) -> None:
        """Re-read the index from disk (to see entries another process flushed)."""
        self._index = self._read_index()

    def _shard(self, name: str):
        handle = self._handles.get(name)
        if handle is None:
            from safetensors import safe_open

            path = self.folder / name
            try:
                handle = safe_open(str(path), framework="pt", device="cpu")
            except Exception as e:  # noqa: BLE001 - safetensors raises its own error types
                raise SMFError(f"text embedding cache shard {path} is unreadable: {e}") from e
            self._handles[name] = handle
        return handle

    # -- _EncoderCache hooks -----------------------------------------------------------------------------
    def _key(self, text: str) -> str:
        return caption_key(self._enc_name, self._max_tokens, text)

    def _lookup(self, key: str) -> torch.Tensor | None:
        rows = self._pending.get(key)
        if rows is not None:
            return rows
        entry = self.index["entries"].get(key)
        if entry is None:
            return None
        shard, start, length = entry
        return self._shard(self.index["shards"][shard]).get_slice("tokens")[start:start + length]

    def _store(self, key: str, rows: torch.Tensor) -> None:
        self._pending[key] = rows.detach().to("cpu", torch.float32).contiguous()

    def _encoder(self) -> FrozenTextEncoder:
        if self._enc is None:
            enc = load_text_encoder(self._enc_name)
            if enc.max_tokens != self._max_tokens:
                raise SMFError(f"text encoder {self._enc_name!r} takes {enc.max_tokens} tokens, the cache keys "
                               f"assumed {self._max_tokens}: pass the encoder object instead of its name")
            self._enc = enc
        return self._enc

    def _dim(self) -> int:
        if self._enc is not None:
            return self._enc.dim
        dim = self.index.get("dims", {}).get(self._ident())
        return int(dim) if dim is not None else self._encoder().dim

    def _ident(self) -> str:
        return f"{self._enc_name}@{self._max_tokens}"

    def _after_compute(self) -> None:
        if len(self._pending) >= self.flush_every:
            self.flush()

    # -- public ------------------------------------------------------------------------------------------
    def get_or_compute(self, texts: list[str], device: torch.device | str | None = None
                       ) -> tuple[torch.Tensor, torch.Tensor]:
        return super().get_or_compute(texts, "cpu" if device is None else device)

    def flush(self) -> None:
        """Write pending rows as a new shard, then the index naming it (both atomically)."""
        if not self._pending:
            return
        from safetensors.torch import save_file

        keys = list(self._pending)
        rows = [self._pending[k] for k in keys]
        dim = rows[0].shape[1]
        name = f"shard-{time.time_ns():x}-{secrets.token_hex(4)}.safetensors"
        with atomic_path(self.folder / name) as tmp:
            save_file({"tokens": torch.cat(rows, 0).contiguous()}, str(tmp),
                      metadata={"encoder": self._enc_name, "max_tokens": str(self._max_tokens),
                                "dim": str(dim)})
        index = self._read_index()  # merge with what is on disk now
        shard_no = len(index["shards"])
        index["shards"].append(name)
        index.setdefault("dims", {})[self._ident()] = int(dim)
        entries = index["entries"]
        start = 0
        for k, r in zip(keys, rows):
            entries[k] = [shard_no, start, int(r.shape[0])]
            start += int(r.shape[0])
        write_text(self.index_path, json.dumps(index, separators=(",", ":")))
        self._index = index
        self._pending.clear()

    def close(self) -> None:
        """Flush and let go of the open shards."""
        self.flush()
        self._handles.clear()

    def __enter__(self) -> "TextEmbeddingCache":
        return self

    def __exit__(self, *exc) -> None:
        if exc[0] is None:
            self.close()
        else:
            self._handles.clear()

    def __len__(self) -> int:
        """Captions cached in this folder (all encoders), flushed or pending."""
        entries = self.index["entries"]
        return len(entries) + sum(1 for k in self._pending if k not in entries)

    def __contains__(self, text: str) -> bool:
        key = self._key(str(text))
        return key in self._pending or key in self.index["entries"]

    @property
    def pending(self) -> int:
        return len(self._pending)

    def __repr__(self) -> str:
        return (f"TextEmbeddingCache({str(self.folder)!r}, encoder={self._enc_name!r}, hits={self.hits}, "
                f"misses={self.misses}, encoder_calls={self.encoder_calls})")


class LRUTextCache(_EncoderCache):
    """In-memory least-recently-used cache of up to ``maxsize`` captions' token rows, on the encoder's device."""

    def __init__(self, encoder: FrozenTextEncoder, maxsize: int = 1024, batch_size: int = 64):
        super().__init__(batch_size)
        if maxsize < 0:
            raise ValueError("maxsize must be >= 0")
        self.encoder = encoder
        self.maxsize = int(maxsize)
        self._rows: OrderedDict[str, torch.Tensor] = OrderedDict()

    def _key(self, text: str) -> str:
        return text

    def _lookup(self, key: str) -> torch.Tensor | None:
        rows = self._rows.get(key)
        if rows is not None:
            self._rows.move_to_end(key)
        return rows

    def _store(self, key: str, rows: torch.Tensor) -> None:
        if self.maxsize == 0:
            return
        self._rows[key] = rows.detach()
        self._rows.move_to_end(key)
        while len(self._rows) > self.maxsize:
            self._rows.popitem(last=False)

    def _encoder(self) -> FrozenTextEncoder:
        return self.encoder

    def get_or_compute(self, texts: list[str], device: torch.device | str | None = None
                       ) -> tuple[torch.Tensor, torch.Tensor]:
        return super().get_or_compute(texts, self.encoder.device if device is None else device)

    def __len__(self) -> int:
        return len(self._rows)

    def __contains__(self, text: str) -> bool:
        return str(text) in self._rows

    def clear(self) -> None:
        self._rows.clear()
