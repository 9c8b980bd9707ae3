"""Frozen text encoders (MiniLM from its wheel, CLIP from a local folder) and the text embedding caches."""

from __future__ import annotations

import json

import pytest
import torch

from stablemofusion.core.errors import SMFError
from stablemofusion.text.cache import LRUTextCache, TextEmbeddingCache, caption_key
from stablemofusion.text.frozen import (CLIPTextEncoder, FrozenTextEncoder, MiniLMEncoder, load_text_encoder,
                                        minilm_folder)

CAPTIONS = [
    "a person walks forward slowly.",
    "someone jumps up and down twice",
    "the man raises his left arm, then waves",
    "a person kicks with the right leg",
]


@pytest.fixture(scope="session")
def minilm() -> MiniLMEncoder:
    return MiniLMEncoder()


class Counting:
    """Wraps an encoder and records every batch it is asked to encode."""

    def __init__(self, encoder: FrozenTextEncoder):
        self.inner = encoder
        self.name, self.dim, self.max_tokens = encoder.name, encoder.dim, encoder.max_tokens
        self.batches: list[list[str]] = []

    @property
    def device(self) -> torch.device:
        return self.inner.device

    @property
    def calls(self) -> int:
        return len(self.batches)

    def encode(self, texts):
        self.batches.append(list(texts))
        return self.inner.encode(texts)


def valid(tokens: torch.Tensor, mask: torch.Tensor, i: int) -> torch.Tensor:
    return tokens[i, mask[i]]


# ---- MiniLM ------------------------------------------------------------------------------------------------

def test_minilm_folder_layout():
    folder = minilm_folder()
    for name in ("config.json", "model.safetensors", "tokenizer.json", "tokenizer_config.json", "vocab.txt"):
        assert (folder / name).is_file(), name


def test_minilm_shapes_mask_and_frozen(minilm):
    assert minilm.name == "minilm" and minilm.dim == 384 and minilm.max_tokens == 77
    tokens, mask = minilm.encode(CAPTIONS)
    lengths = [len(minilm.tokenizer(c)["input_ids"]) for c in CAPTIONS]  # includes [CLS] and [SEP]
    assert tokens.shape == (len(CAPTIONS), max(lengths), 384) and tokens.dtype == torch.float32
    assert mask.dtype == torch.bool
    assert mask.sum(1).tolist() == lengths
    for i, n in enumerate(lengths):
        assert mask[i, :n].all() and not mask[i, n:].any()
        assert torch.all(tokens[i, n:] == 0)
    assert not tokens.requires_grad
    assert all(not p.requires_grad for p in minilm.parameters())
    assert not minilm.model.training
    minilm.train()  # a parent module's .train() must not switch dropout on
    assert not minilm.training and not minilm.model.training


def test_minilm_different_sentences_differ(minilm):
    tokens, mask = minilm.encode(["a person walks forward", "a person sits down"])
    a, b = valid(tokens, mask, 0), valid(tokens, mask, 1)
    assert a.shape == b.shape  # same token count, yet different embeddings
    assert (a - b).abs().max() > 0.1
    assert (a.mean(0) - b.mean(0)).norm() > 0.1


def test_minilm_alone_equals_batched_and_deterministic(minilm):
    batch_t, batch_m = minilm.encode(CAPTIONS)
    for i, caption in enumerate(CAPTIONS):
        alone_t, alone_m = minilm.encode([caption])
        assert alone_m.all()
        torch.testing.assert_close(alone_t[0], valid(batch_t, batch_m, i), atol=1e-5, rtol=0)
    again_t, again_m = minilm.encode(CAPTIONS)
    assert torch.equal(again_m, batch_m) and torch.equal(again_t, batch_t)


def test_minilm_truncates_and_handles_edge_cases(minilm):
    tokens, mask = minilm.encode(["walk " * 200, "run"])
    assert tokens.shape == (2, 77, 384) and mask[0].all() and mask[1].sum() == 3
    tokens, mask = minilm.encode([])
    assert tokens.shape == (0, 0, 384) and mask.shape == (0, 0)
    with pytest.raises(TypeError):
        minilm.encode("a single string")


def test_minilm_feeds_text_transformer(minilm):
    from stablemofusion.text.transformer import TextTransformer

    tokens, mask = minilm.encode(CAPTIONS)
    tt = TextTransformer(minilm.dim, latent=32, layers=1, heads=2, ff=64, max_tokens=minilm.max_tokens)
    out = tt(tokens, mask)
    out.sum().backward()  # no_grad (not inference_mode) outputs can feed a trained module
    assert tt.proj.weight.grad is not None


# ---- load_text_encoder and CLIP ------------------------------------------------------------------------------

def test_load_text_encoder_errors(tmp_path):
    with pytest.raises(SMFError, match="unknown text encoder"):
        load_text_encoder("bert-large")
    with pytest.raises(SMFError, match="needs a folder"):
        load_text_encoder("clip:")
    missing = tmp_path / "no-clip-here"
    with pytest.raises(SMFError, match="CLIP weights not found") as e:
        load_text_encoder(f"clip:{missing}")
    assert str(missing) in str(e.value) and "openai/clip-vit-base-patch32" in str(e.value)
    partial = tmp_path / "partial"
    partial.mkdir()
    (partial / "config.json").write_text("{}")
    with pytest.raises(SMFError, match="model weights") as e:
        CLIPTextEncoder(partial)
    assert str(partial) in str(e.value)
    with pytest.raises(SMFError, match="do not fit the model"):  # a BERT folder is no CLIP: refuse random weights
        CLIPTextEncoder(minilm_folder())


def make_tiny_clip(folder, seed=0):
    """A randomly initialised tiny full CLIP model (text + vision) and a byte-level tokenizer, saved in HF layout.

    The vocabulary (vocab.json, as in openai/clip-vit-base-patch32) is the 256 byte symbols, each also with
    CLIP's end-of-word suffix, plus the two special tokens; merges.txt is empty, so words are spelt letter
    by letter.
    """
    from tokenizers.pre_tokenizers import ByteLevel
    from transformers import CLIPConfig, CLIPModel, CLIPTextConfig, CLIPTokenizer, CLIPVisionConfig

    chars = sorted(ByteLevel.alphabet())
    vocab = {c: i for i, c in enumerate(chars)}
    vocab.update({c + "</w>": len(chars) + i for i, c in enumerate(chars)})
    vocab["<|startoftext|>"] = len(vocab)
    vocab["<|endoftext|>"] = len(vocab)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "vocab.json").write_text(json.dumps(vocab), encoding="utf-8")
    (folder / "merges.txt").write_text("#version: 0.2\n", encoding="utf-8")
    tokenizer = CLIPTokenizer.from_pretrained(folder, model_max_length=77)
    text = CLIPTextConfig(vocab_size=len(vocab), hidden_size=32, intermediate_size=64, num_hidden_layers=2,
                          num_attention_heads=4, max_position_embeddings=77, projection_dim=16,
                          bos_token_id=vocab["<|startoftext|>"], eos_token_id=vocab["<|endoftext|>"],
                          pad_token_id=vocab["<|endoftext|>"])
    vision = CLIPVisionConfig(hidden_size=32, intermediate_size=64, num_hidden_layers=1, num_attention_heads=4,
                              image_size=32, patch_size=16, projection_dim=16)
    torch.manual_seed(seed)
    model = CLIPModel(CLIPConfig(text_config=text.to_dict(), vision_config=vision.to_dict(), projection_dim=16))
    model.eval()
    model.save_pretrained(folder)
    tokenizer.save_pretrained(folder)
    return model, tokenizer


def test_clip_text_encoder_from_tiny_local_folder(tmp_path):
    folder = tmp_path / "tiny-clip"
    ref_model, tokenizer = make_tiny_clip(folder)
    enc = load_text_encoder(f"clip:{folder}")
    assert isinstance(enc, CLIPTextEncoder)
    assert enc.name == f"clip:{folder}" and enc.dim == 32 and enc.max_tokens == 77
    texts = ["a person walks", "hi", "walk " * 40]
    tokens, mask = enc.encode(texts)
    assert tokens.shape == (3, 77, 32) and tokens.dtype == torch.float32  # the long one is cut at 77
    assert mask.sum(1).tolist() == [14, 4, 77]  # start + 12 letters (no merges) + end; start + h + i + end
    batch = tokenizer(texts, padding=True, truncation=True, max_length=77, return_tensors="pt")
    assert torch.equal(mask, batch["attention_mask"].bool())
    with torch.no_grad():
        ref = ref_model.text_model(**batch).last_hidden_state
    torch.testing.assert_close(tokens[mask], ref[mask], atol=1e-5, rtol=0)
    assert torch.all(tokens[~mask] == 0)
    alone_t, _ = enc.encode(["hi"])
    torch.testing.assert_close(alone_t[0], valid(tokens, mask, 1), atol=1e-5, rtol=0)
    assert all(not p.requires_grad for p in enc.parameters()) and not enc.model.training


# ---- disk cache --------------------------------------------------------------------------------------------

def test_cache_hits_after_first_call_and_matches_direct(minilm, tmp_path):
    enc = Counting(minilm)
    cache = TextEmbeddingCache(tmp_path / "cache", enc)
    direct_t, direct_m = minilm.encode(CAPTIONS)
    t1, m1 = cache.get_or_compute(CAPTIONS)
    assert enc.calls == 1 and cache.misses == len(CAPTIONS) and cache.hits == 0
    assert torch.equal(m1, direct_m)
    torch.testing.assert_close(t1, direct_t, atol=1e-5, rtol=0)
    t2, m2 = cache.get_or_compute(CAPTIONS)
    assert enc.calls == 1 and cache.hits == len(CAPTIONS)
    assert torch.equal(t2, t1) and torch.equal(m2, m1)
    # a mixed request encodes only the new caption, once even if repeated
    t3, m3 = cache.get_or_compute([CAPTIONS[2], "a person turns around", "a person turns around"])
    assert enc.batches[-1] == ["a person turns around"] and enc.calls == 2
    assert torch.equal(t3[0, m3[0]], valid(t1, m1, 2))
    torch.testing.assert_close(t3[1], t3[2])
    assert len(cache) == len(CAPTIONS) + 1 and "a person turns around" in cache


def test_cache_persists_across_objects_and_loads_encoder_lazily(minilm, tmp_path):
    folder = tmp_path / "cache"
    with TextEmbeddingCache(folder, Counting(minilm)) as cache:
        t1, m1 = cache.get_or_compute(CAPTIONS)
        assert cache.pending == len(CAPTIONS)
    assert cache.pending == 0
    index = json.loads((folder / "index.json").read_text())
    assert len(index["shards"]) == 1 and len(index["entries"]) == len(CAPTIONS)
    key = caption_key("minilm", 77, CAPTIONS[0])
    assert index["entries"][key][1:] == [0, int(m1[0].sum())]

    enc2 = Counting(minilm)
    cache2 = TextEmbeddingCache(folder, enc2)
    t2, m2 = cache2.get_or_compute(list(reversed(CAPTIONS)))
    assert enc2.calls == 0 and cache2.hits == len(CAPTIONS)
    assert torch.equal(t2, t1.flip(0)) and torch.equal(m2, m1.flip(0))

    by_name = TextEmbeddingCache(folder, "minilm")  # all cached: the language model is never loaded
    t3, _ = by_name.get_or_compute(CAPTIONS[:2])
    assert by_name._enc is None and torch.equal(t3, t1[:2, :t3.shape[1]])


def test_cache_auto_flush(minilm, tmp_path):
    folder = tmp_path / "cache"
    cache = TextEmbeddingCache(folder, Counting(minilm), batch_size=3, flush_every=2)
    cache.get_or_compute(CAPTIONS)
    assert cache.encoder_calls == 2  # 4 captions in batches of 3
    assert cache.pending == 0 and len(TextEmbeddingCache(folder, "minilm")) == len(CAPTIONS)


def test_failed_flush_leaves_previous_state(minilm, tmp_path, monkeypatch):
    import safetensors.torch

    import stablemofusion.text.cache as cache_mod

    folder = tmp_path / "cache"
    cache = TextEmbeddingCache(folder, Counting(minilm))
    ref_t, ref_m = cache.get_or_compute(CAPTIONS[:2])
    cache.flush()
    files_before = sorted(p.name for p in folder.iterdir())
    index_before = (folder / "index.json").read_bytes()

    cache.get_or_compute(CAPTIONS[2:])

    def half_write(tensors, filename, metadata=None):
        with open(filename, "wb") as f:
            f.write(b"\x00" * 100)  # a partial shard ...
        raise OSError("disk full")  # ... then the write fails

    monkeypatch.setattr(safetensors.torch, "save_file", half_write)
    with pytest.raises(OSError, match="disk full"):
        cache.flush()
    monkeypatch.undo()
    assert sorted(p.name for p in folder.iterdir()) == files_before  # no partial shard left visible
    assert (folder / "index.json").read_bytes() == index_before

    def fail_index(path, text):
        raise OSError("crash before the index was written")

    monkeypatch.setattr(cache_mod, "write_text", fail_index)
    with pytest.raises(OSError, match="crash"):
        cache.flush()
    monkeypatch.undo()
    assert (folder / "index.json").read_bytes() == index_before  # the new shard exists but is not referenced

    enc = Counting(minilm)
    fresh = TextEmbeddingCache(folder, enc)
    assert len(fresh) == 2 and CAPTIONS[0] in fresh and CAPTIONS[2] not in fresh
    t, m = fresh.get_or_compute(CAPTIONS[:2])
    assert enc.calls == 0 and torch.equal(t, ref_t) and torch.equal(m, ref_m)

    cache.flush()  # the rows were kept: a retry succeeds
    fresh.refresh()
    assert len(fresh) == len(CAPTIONS)
    fresh.get_or_compute(CAPTIONS)
    assert enc.calls == 0


# ---- LRU cache ---------------------------------------------------------------------------------------------

def test_lru_cache_hits_and_evicts(minilm):
    enc = Counting(minilm)
    lru = LRUTextCache(enc, maxsize=2)
    a, b, c = CAPTIONS[:3]
    ta, ma = lru.get_or_compute([a])
    lru.get_or_compute([b])
    assert enc.calls == 2 and len(lru) == 2
    t, m = lru.get_or_compute([b, a])  # a is now the most recently used
    assert enc.calls == 2 and lru.hits == 2
    torch.testing.assert_close(t[1, m[1]], ta[0])
    lru.get_or_compute([c])  # evicts b, the least recently used
    assert len(lru) == 2 and a in lru and c in lru and b not in lru
    lru.get_or_compute([b])
    assert enc.calls == 4 and enc.batches[-1] == [b]
    # a request larger than maxsize still gets all its rows
    direct_t, direct_m = minilm.encode(CAPTIONS)
    t, m = LRUTextCache(Counting(minilm), maxsize=1).get_or_compute(CAPTIONS)
    assert torch.equal(m, direct_m)
    torch.testing.assert_close(t, direct_t, atol=1e-5, rtol=0)
