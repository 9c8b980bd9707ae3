"""The ORIGINAL T2M evaluator (Guo et al. 2022, repo EricGuo5513/text-to-motion) for users who have its files.

Every HumanML3D / KIT-ML paper reports FID, R-precision, matching score and diversity with the same
pretrained text/motion matching model. This module re-implements its architecture so that the official
weights load with ``strict=True``, and the GloVe word vectorizer that feeds its text side. Nothing is
downloaded: the user points at the folders they already have.

Files (official layout; ``<dataset>`` is ``t2m`` for HumanML3D, ``kit`` for KIT-ML)::

    <root>/<dataset>/text_mot_match/model/finest.tar     torch.save dict with the keys
                                                         'text_encoder', 'motion_encoder', 'movement_encoder'
    <root>/t2m/Comp_v6_KLD01/meta/{mean,std}.npy         evaluator normalisation, (263,)
    <root>/kit/Comp_v6_KLD005/meta/{mean,std}.npy        evaluator normalisation, (251,)
    <glove>/our_vab_data.npy                             (V, 300) word vectors
    <glove>/our_vab_words.pkl                            list of the V words
    <glove>/our_vab_idx.pkl                              dict word -> row index

Networks (state-dict names as in the official checkpoint):

* ``MovementConvEncoder``: features without the 4 foot-contact dims, normalised with the meta mean/std ->
  two Conv1d(k=4, s=2, p=1) + Dropout + LeakyReLU (time / 4) -> Linear.
* ``MotionEncoderBiGRUCo``: Linear -> bidirectional GRU from a learned initial state over ``frames // 4``
  steps -> concatenated last states -> Linear, LayerNorm, LeakyReLU, Linear -> 512.
* ``TextEncoderBiGRUCo``: GloVe vector + Linear(POS one-hot) -> Linear -> bidirectional GRU from a learned
  initial state -> concatenated last states -> MLP -> 512.

Text input is HumanML3D's tagged tokens (``word/POS``, the second ``#`` field of a ``texts/*.txt`` line),
wrapped in ``sos/OTHER`` ... ``eos/OTHER`` and cut to 20 tokens, exactly as the official data loader does.
Plain captions cannot be embedded: the POS tags come from spaCy in the dataset's own preprocessing.

Motion input follows the official evaluation loader: lengths are cut down to a multiple of 4 frames, and
each motion is normalised and zero-padded to 196 frames (frames past its length are replaced by those
zeros), so whatever a padded batch holds beyond each length never changes the embedding. A motion longer
than 196 frames (the official loader never has one) is embedded over its whole length, followed by zeros.

Example::

    ev = T2MOriginalEvaluator.from_files("checkpoints", "glove", dataset="t2m")
    m = ev.embed_motion(torch.from_numpy(vecs[None]).float(), [len(vecs)])      # (1, 512)
    t = ev.embed_tokens([["a/DET", "man/NOUN", "kick/VERB"]])                   # (1, 512)
    dist = torch.linalg.vector_norm(m - t, dim=-1)                              # matching distance
"""

from __future__ import annotations

import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from torch import nn
from torch.nn.utils.rnn import pack_padded_sequence

from ..core.errors import SMFError

CONTACT_DIMS = 4  # last 4 feature dims (foot contacts) are not seen by the movement encoder
UNIT_LENGTH = 4  # frames per motion-GRU step (two stride-2 convolutions)
MAX_TEXT_LEN = 20  # tokens kept per caption, before sos/eos
MAX_MOTION_LEN = 196  # frames every motion is zero-padded to by the official evaluation loader
WORD_DIM = 300  # GloVe
EMBED_DIM = 512

# Part-of-speech classes of the one-hot, in the official order.
POS_CLASSES = ("VERB", "NOUN", "DET", "ADP", "NUM", "AUX", "PRON", "ADJ", "ADV",
               "Loc_VIP", "Body_VIP", "Obj_VIP", "Act_VIP", "Desc_VIP", "OTHER")
POS_INDEX = {p: i for i, p in enumerate(POS_CLASSES)}

# Words whose POS class is replaced by a "very important" class (checked in this order).
VIP_WORDS: dict[str, frozenset[str]] = {
    "Loc_VIP": frozenset("left right clockwise counterclockwise anticlockwise forward back backward up down "
                         "straight curve".split()),
    "Body_VIP": frozenset("arm chin foot feet face hand mouth leg waist eye knee shoulder thigh".split()),
    "Obj_VIP": frozenset("stair dumbbell chair window floor car ball handrail baseball basketball".split()),
    "Act_VIP": frozenset("walk run swing pick bring kick put squat throw hop dance jump turn stumble stop sit "
                         "lift lower raise wash stand kneel stroll rub bend balance flap jog shuffle lean rotate "
                         "spin spread climb".split()),
    "Desc_VIP": frozenset("slowly carefully fast careful slow quickly happy angry sad happily angrily "
                          "sadly".split()),
}


@dataclass(frozen=True)
class DatasetSpec:
    """Where the official files of one dataset live and how wide its features are."""

    name: str
    dim_pose: int
    meta: str  # folder holding mean.npy / std.npy, relative to <root>


DATASETS = {
    "t2m": DatasetSpec("t2m", 263, "t2m/Comp_v6_KLD01/meta"),
    "kit": DatasetSpec("kit", 251, "kit/Comp_v6_KLD005/meta"),
}
CHECKPOINT = "text_mot_match/model/finest.tar"  # relative to <root>/<dataset>
GLOVE_FILES = ("our_vab_data.npy", "our_vab_words.pkl", "our_vab_idx.pkl")


# ---------------------------------------------------------------------------------------------- networks

def _final_states(gru: nn.GRU, x: torch.Tensor, lengths: torch.Tensor, h0: nn.Parameter) -> torch.Tensor:
    """Bidirectional GRU from the learned state ``h0`` (2, 1, H) over the first ``lengths`` steps -> (B, 2H)."""
    packed = pack_padded_sequence(x, lengths.cpu(), batch_first=True, enforce_sorted=False)
    _, h = gru(packed, h0.expand(-1, x.shape[0], -1).contiguous())  # (2, B, H), batch back in input order
    return torch.cat([h[0], h[1]], dim=-1)


class MovementConvEncoder(nn.Module):
    """(B, T, dim_pose - 4) normalised features -> (B, T // 4, output_size) movement codes."""

    def __init__(self, input_size: int, hidden_size: int = 512, output_size: int = 512):
        super().__init__()
        self.main = nn.Sequential(
            nn.Conv1d(input_size, hidden_size, 4, 2, 1), nn.Dropout(0.2), nn.LeakyReLU(0.2),
            nn.Conv1d(hidden_size, output_size, 4, 2, 1), nn.Dropout(0.2), nn.LeakyReLU(0.2),
        )
        self.out_net = nn.Linear(output_size, output_size)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.out_net(self.main(x.transpose(1, 2)).transpose(1, 2))


class MotionEncoderBiGRUCo(nn.Module):
    """Movement codes (B, S, input_size), valid steps (B,) -> (B, output_size)."""

    def __init__(self, input_size: int = 512, hidden_size: int = 1024, output_size: int = 512):
        super().__init__()
        self.input_emb = nn.Linear(input_size, hidden_size)
        self.gru = nn.GRU(hidden_size, hidden_size, batch_first=True, bidirectional=True)
        self.output_net = nn.Sequential(nn.Linear(2 * hidden_size, hidden_size), nn.LayerNorm(hidden_size),
                                        nn.LeakyReLU(0.2), nn.Linear(hidden_size, output_size))
        self.hidden = nn.Parameter(torch.randn(2, 1, hidden_size))

    def forward(self, movements: torch.Tensor, m_lens: torch.Tensor) -> torch.Tensor:
        return self.output_net(_final_states(self.gru, self.input_emb(movements), m_lens, self.hidden))


class TextEncoderBiGRUCo(nn.Module):
    """GloVe vectors (B, L, 300), POS one-hots (B, L, 15), lengths (B,) -> (B, output_size)."""

    def __init__(self, word_size: int = WORD_DIM, pos_size: int = len(POS_CLASSES), hidden_size: int = 512,
                 output_size: int = 512):
        super().__init__()
        self.pos_emb = nn.Linear(pos_size, word_size)
        self.input_emb = nn.Linear(word_size, hidden_size)
        self.gru = nn.GRU(hidden_size, hidden_size, batch_first=True, bidirectional=True)
        self.output_net = nn.Sequential(nn.Linear(2 * hidden_size, hidden_size), nn.LayerNorm(hidden_size),
                                        nn.LeakyReLU(0.2), nn.Linear(hidden_size, output_size))
        self.hidden = nn.Parameter(torch.randn(2, 1, hidden_size))

    def forward(self, word_embs: torch.Tensor, pos_onehot: torch.Tensor, cap_lens: torch.Tensor) -> torch.Tensor:
        x = self.input_emb(word_embs + self.pos_emb(pos_onehot))
        return self.output_net(_final_states(self.gru, x, cap_lens, self.hidden))


# ------------------------------------------------------------------------------------------------- text

def pos_class(word: str, pos: str) -> str:
    """POS class of an in-vocabulary word: its VIP class if it has one, else ``pos`` if known, else OTHER."""
    for cls, words in VIP_WORDS.items():
        if word in words:
            return cls
    return pos if pos in POS_INDEX else "OTHER"


def wrap_tokens(tokens: Sequence[str], max_text_len: int = MAX_TEXT_LEN) -> list[str]:
    """``sos/OTHER`` + the first ``max_text_len`` tokens + ``eos/OTHER`` (padding is left to the batcher)."""
    return ["sos/OTHER", *list(tokens)[:max_text_len], "eos/OTHER"]


def split_token(token: str) -> tuple[str, str]:
    """``'word/POS'`` -> (word, POS); raises SMFError for an untagged token."""
    word, sep, pos = token.rpartition("/")
    if not sep or not word or not pos:
        raise SMFError(f"the original T2M evaluator needs POS-tagged tokens like 'walk/VERB', got {token!r}")
    return word, pos


class WordVectorizer:
    """GloVe lookup of ``word/POS`` tokens -> (300-d vector, 15-d POS one-hot), as in the official code.

    A word outside the vocabulary gets the ``unk`` vector and the OTHER class (its tag is ignored).
    """

    def __init__(self, vectors: np.ndarray, words: Sequence[str], word2idx: dict[str, int]):
        vectors = np.asarray(vectors, dtype=np.float32)
        if vectors.ndim != 2 or vectors.shape[1] != WORD_DIM:
            raise SMFError(f"GloVe vectors must be (V, {WORD_DIM}), got {tuple(vectors.shape)}")
        self.vectors = vectors
        try:
            self.word2idx = {w: int(word2idx[w]) for w in words}
        except KeyError as e:
            raise SMFError(f"GloVe word list and index disagree: no index for {e.args[0]!r}") from None
        bad = [w for w, i in self.word2idx.items() if not 0 <= i < len(vectors)]
        if bad:
            raise SMFError(f"GloVe index points outside the {len(vectors)} vectors (word {bad[0]!r})")
        missing = [w for w in ("unk", "sos", "eos") if w not in self.word2idx]
        if missing:
            raise SMFError(f"GloVe vocabulary lacks the special word(s) {missing}")

    @classmethod
    def from_dir(cls, glove: str | Path, prefix: str = "our_vab") -> "WordVectorizer":
        """Load ``<glove>/<prefix>_data.npy``, ``_words.pkl``, ``_idx.pkl``; one-line SMFError on a missing file."""
        glove = Path(glove)
        data, words, idx = (glove / f"{prefix}{s}" for s in ("_data.npy", "_words.pkl", "_idx.pkl"))
        for p in (data, words, idx):
            _need(p, "GloVe file")
        try:
            vectors = np.load(data)
            with open(words, "rb") as f:
                word_list = pickle.load(f)
            with open(idx, "rb") as f:
                word2idx = pickle.load(f)
        except Exception as e:  # noqa: BLE001 - any unreadable file is a user error here
            raise SMFError(f"cannot read GloVe files in {glove}: {type(e).__name__}: {e}") from None
        if not isinstance(word2idx, dict):
            raise SMFError(f"{idx}: expected a dict word -> index, got {type(word2idx).__name__}")
        return cls(vectors, list(word_list), word2idx)

    def __len__(self) -> int:
        return len(self.word2idx)

    def pos_onehot(self, cls: str) -> np.ndarray:
        v = np.zeros(len(POS_CLASSES), dtype=np.float32)
        v[POS_INDEX.get(cls, POS_INDEX["OTHER"])] = 1.0
        return v

    def __getitem__(self, token: str) -> tuple[np.ndarray, np.ndarray]:
        word, pos = split_token(token)
        if word in self.word2idx:
            return self.vectors[self.word2idx[word]], self.pos_onehot(pos_class(word, pos))
        return self.vectors[self.word2idx["unk"]], self.pos_onehot("OTHER")

    def batch(self, token_lists: Sequence[Sequence[str]], max_text_len: int = MAX_TEXT_LEN
              ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Token lists -> word vectors (B, L, 300), POS one-hots (B, L, 15), lengths (B,) incl. sos/eos.

        Padding uses ``unk/OTHER`` as the official loader does (the GRU never reads it: sequences are packed).
        """
        wrapped = [wrap_tokens(t, max_text_len) for t in token_lists]
        L = max(len(t) for t in wrapped)
        words = np.zeros((len(wrapped), L, WORD_DIM), dtype=np.float32)
        pos = np.zeros((len(wrapped), L, len(POS_CLASSES)), dtype=np.float32)
        for i, toks in enumerate(wrapped):
            for j, tok in enumerate(toks + ["unk/OTHER"] * (L - len(toks))):
                words[i, j], pos[i, j] = self[tok]
        lengths = torch.tensor([len(t) for t in wrapped], dtype=torch.long)
        return torch.from_numpy(words), torch.from_numpy(pos), lengths


# ------------------------------------------------------------------------------------------------ loader

def _need(path: Path, what: str) -> Path:
    if not path.is_file():
        raise SMFError(f"original T2M evaluator: missing {what} {path}")
    return path


def official_paths(root: str | Path, glove: str | Path, dataset: str = "t2m") -> dict[str, Path]:
    """The files :meth:`T2MOriginalEvaluator.from_files` reads, by role."""
    if dataset not in DATASETS:
        raise SMFError(f"original T2M evaluator: dataset must be one of {sorted(DATASETS)}, got {dataset!r}")
    root, glove, spec = Path(root), Path(glove), DATASETS[dataset]
    return {
        "checkpoint": root / spec.name / CHECKPOINT,
        "mean": root / spec.meta / "mean.npy",
        "std": root / spec.meta / "std.npy",
        **{name: glove / name for name in GLOVE_FILES},
    }


def _load_checkpoint(path: Path, allow_pickle: bool) -> dict:
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=not allow_pickle)
    except pickle.UnpicklingError as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise SMFError(f"{path}: holds more than tensors and cannot be loaded safely ({first}); "
                       "pass allow_pickle=True if you trust the file") from None
    except Exception as e:  # noqa: BLE001 - corrupt / not a torch file
        raise SMFError(f"{path}: not a readable torch checkpoint ({type(e).__name__})") from None
    if not isinstance(ckpt, dict):
        raise SMFError(f"{path}: expected a dict of state dicts, got {type(ckpt).__name__}")
    return ckpt


def _load_part(module: nn.Module, ckpt: dict, key: str, path: Path) -> None:
    """Strict load of ``ckpt[key]`` into ``module`` with a one-line SMFError naming what does not fit."""
    if key not in ckpt:
        raise SMFError(f"{path}: no key {key!r} (has {sorted(map(str, ckpt))})")
    state = ckpt[key]
    if not isinstance(state, dict):
        raise SMFError(f"{path}: {key!r} is not a state dict")
    own = module.state_dict()
    missing = [k for k in own if k not in state]
    unexpected = [k for k in state if k not in own]
    if missing or unexpected:
        raise SMFError(f"{path}: {key!r} does not match the T2M architecture "
                       f"(missing {missing[:3]}, unexpected {unexpected[:3]})")
    for k, v in own.items():
        if tuple(state[k].shape) != tuple(v.shape):
            raise SMFError(f"{path}: {key}.{k} has shape {tuple(state[k].shape)}, expected {tuple(v.shape)}")
    module.load_state_dict(state, strict=True)


class T2MOriginalEvaluator(nn.Module):
    """The official text/motion matching model: ``embed_motion`` and ``embed_tokens`` into one 512-d space.

    Build it with :meth:`from_files`. Matching distance is the Euclidean distance between embeddings.
    """

    def __init__(self, dataset: str = "t2m", mean: np.ndarray | None = None, std: np.ndarray | None = None,
                 vectorizer: WordVectorizer | None = None):
        super().__init__()
        if dataset not in DATASETS:
            raise SMFError(f"original T2M evaluator: dataset must be one of {sorted(DATASETS)}, got {dataset!r}")
        self.dataset = dataset
        self.dim_pose = DATASETS[dataset].dim_pose
        self.movement_encoder = MovementConvEncoder(self.dim_pose - CONTACT_DIMS, 512, 512)
        self.motion_encoder = MotionEncoderBiGRUCo(512, 1024, EMBED_DIM)
        self.text_encoder = TextEncoderBiGRUCo(WORD_DIM, len(POS_CLASSES), 512, EMBED_DIM)
        self.register_buffer("mean", torch.as_tensor(np.zeros(self.dim_pose) if mean is None else mean,
                                                     dtype=torch.float32))
        self.register_buffer("std", torch.as_tensor(np.ones(self.dim_pose) if std is None else std,
                                                    dtype=torch.float32))
        self.vectorizer = vectorizer

    @classmethod
    def from_files(cls, root: str | Path, glove: str | Path, dataset: str = "t2m",
                   device: str | torch.device = "cpu", allow_pickle: bool = False) -> "T2MOriginalEvaluator":
        """Load the official evaluator from ``<root>`` (the T2M ``checkpoints`` folder) and ``<glove>``.

        Raises SMFError (one line) naming a missing file, a missing/mismatched checkpoint key or a wrong shape.
        ``allow_pickle`` lets torch unpickle arbitrary objects in ``finest.tar`` (only for a file you trust;
        plain tensors, numbers and optimizer states load without it).
        """
        paths = official_paths(root, glove, dataset)
        for role, p in paths.items():
            _need(p, "checkpoint" if role == "checkpoint" else "meta file" if role in ("mean", "std")
                  else "GloVe file")
        dim = DATASETS[dataset].dim_pose
        stats = {}
        for role in ("mean", "std"):
            try:
                a = np.load(paths[role])
            except Exception as e:  # noqa: BLE001
                raise SMFError(f"{paths[role]}: not a readable .npy file ({type(e).__name__})") from None
            if a.shape != (dim,):
                raise SMFError(f"{paths[role]}: expected shape ({dim},) for {dataset}, got {a.shape}")
            stats[role] = a
        if np.any(stats["std"] == 0):
            raise SMFError(f"{paths['std']}: contains zeros")
        vectorizer = WordVectorizer.from_dir(glove)
        model = cls(dataset, stats["mean"], stats["std"], vectorizer)
        ckpt = _load_checkpoint(paths["checkpoint"], allow_pickle)
        for key in ("text_encoder", "motion_encoder", "movement_encoder"):
            _load_part(getattr(model, key), ckpt, key, paths["checkpoint"])
        return model.to(device).eval()

    @property
    def device(self) -> torch.device:
        return self.mean.device

    @torch.no_grad()
    def embed_motion(self, features: torch.Tensor, lengths: torch.Tensor | Sequence[int]) -> torch.Tensor:
        """Raw features (B, T, dim_pose) in dataset units, lengths (B,) frames -> embeddings (B, 512).

        Lengths are cut down to a multiple of 4 (at least 4 frames needed); frames past them are ignored and
        the result does not depend on T (see the module docstring for the official zero padding).
        """
        if features.ndim != 3 or features.shape[-1] != self.dim_pose:
            raise SMFError(f"original T2M evaluator ({self.dataset}) expects (B, T, {self.dim_pose}) features, "
                           f"got {tuple(features.shape)}")
        B, T, _ = features.shape
        lengths = torch.as_tensor(lengths, dtype=torch.long).reshape(-1).to(self.device)
        if lengths.numel() != B:
            raise SMFError(f"got {lengths.numel()} lengths for {B} motions")
        if B == 0:
            return torch.zeros(0, EMBED_DIM, device=self.device)
        if int(lengths.min()) < UNIT_LENGTH or int(lengths.max()) > T:
            raise SMFError(f"motion lengths must be in [{UNIT_LENGTH}, {T}] frames, got "
                           f"{int(lengths.min())}..{int(lengths.max())}")
        lengths = lengths // UNIT_LENGTH * UNIT_LENGTH
        # The official loader zero-pads every normalised motion to 196 frames; the convolutions see those zeros
        # past the end of any shorter motion, and none past a 196-frame one. Do the same whatever T is.
        P = max(MAX_MOTION_LEN, int(lengths.max()) + UNIT_LENGTH)
        x = features[:, :P].to(self.device, torch.float32)
        x = torch.nn.functional.pad(x, (0, 0, 0, P - x.shape[1]))
        x = (x - self.mean) / self.std
        valid = torch.arange(P, device=self.device)[None, :, None] < lengths[:, None, None]
        x = torch.where(valid, x, torch.zeros((), device=self.device))[..., :-CONTACT_DIMS]
        movements = self.movement_encoder(x)
        full = lengths == MAX_MOTION_LEN
        if full.any():
            movements[full, :MAX_MOTION_LEN // UNIT_LENGTH] = self.movement_encoder(x[full, :MAX_MOTION_LEN])
        return self.motion_encoder(movements, lengths // UNIT_LENGTH)

    @torch.no_grad()
    def embed_tokens(self, token_lists: Sequence[Sequence[str] | str]) -> torch.Tensor:
        """POS-tagged captions -> embeddings (B, 512).

        Each item is a list of ``word/POS`` tokens, or one string of them separated by spaces (the second
        ``#`` field of a HumanML3D ``texts/*.txt`` line). At most 20 tokens are used, as in the official code.
        """
        if self.vectorizer is None:
            raise SMFError("original T2M evaluator has no GloVe vectorizer; build it with from_files()")
        lists = [t.split() if isinstance(t, str) else list(t) for t in token_lists]
        if not lists:
            return torch.zeros(0, EMBED_DIM, device=self.device)
        words, pos, lengths = self.vectorizer.batch(lists)
        return self.text_encoder(words.to(self.device), pos.to(self.device), lengths)

    def embed_text(self, token_lists: Sequence[Sequence[str] | str]) -> torch.Tensor:
        """Same as :meth:`embed_tokens` (the original text side takes ``word/POS`` tokens, not embeddings)."""
        return self.embed_tokens(token_lists)

    def embed_captions(self, captions: Sequence[str]) -> torch.Tensor:
        """Not possible: the original evaluator needs POS-tagged tokens. Always raises SMFError."""
        raise SMFError("the original T2M evaluator needs POS-tagged tokens (word/POS, e.g. 'walk/VERB' as in "
                       "HumanML3D texts/*.txt), not plain captions; use embed_tokens()")


def read_humanml_tokens(path: str | Path) -> list[list[str]]:
    """The ``word/POS`` token lists of a HumanML3D/KIT ``texts/<id>.txt`` file, one per caption line."""
    out = []
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        fields = line.strip().split("#")
        if len(fields) >= 2 and fields[1].strip():
            out.append(fields[1].split())
    return out


__all__ = ["T2MOriginalEvaluator", "WordVectorizer", "MovementConvEncoder", "MotionEncoderBiGRUCo",
           "TextEncoderBiGRUCo", "POS_CLASSES", "VIP_WORDS", "pos_class", "wrap_tokens", "official_paths",
           "read_humanml_tokens", "DATASETS"]
