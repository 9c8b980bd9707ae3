"""The out-of-domain detector: a small classifier on the sentence embedding, trained on every training caption
(in domain) against foreign captions (:mod:`.foreign`), with a calibrated threshold.

Why not the closest action sentence: a prompt with a style, a persona and an irrelevant detail sits far from
every bare "a person ..." sentence, and a foreign action with a familiar subject sits close to one. The
training captions carry the same subjects, styles and details as the foreign captions (both come from the
corpus caption grammar), so the classifier can only separate them by the action. Measured on held-out data
(``benchmarks/ood_threshold.py``, docs/prompts.md).

The detector is ``ood.safetensors`` beside ``actions.json`` (which names it, with the calibration): an MLP
384 -> 256 -> 1 in float16 (about 200 kB), depending only on the text encoder and the captions, not on the
denoiser's weights. Its score is ``sigmoid((logit - offset) / scale)``: 0.5 at the calibrated threshold,
where ``offset`` is the logit below which :data:`FLAG_RATE` of the calibration prompts fall
(:func:`calibration_inside`: free-form in-domain prompts written the way users type them, which neither the
classifier nor the motion model saw).
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from ..core.errors import SMFError
from ..motion.arrays import numpy_edge
from .frozen import sentence_embedding
from .names import DETECTOR_FILE

FLAG_RATE = 0.05  # share of the calibration prompts (calibration_inside) the threshold flags
HIDDEN, DROPOUT, EPOCHS, LR, WEIGHT_DECAY, BATCH = 256, 0.2, 15, 3e-3, 1e-2, 512
FOREIGN_PER_PHRASE = 24  # foreign captions per foreign phrasing (assets/lexicons/foreign.txt)
CALIBRATION_FILE = "{lexicon}-calibration.txt"  # in assets/lexicons: free-form in-domain prompts
HELDOUT_PER_PAIR = 2  # held-out captions per (content, style) pair for the calibration


class DomainClassifier(nn.Module):
    """Sentence embedding (B, dim) -> in-domain logit (B,)."""

    def __init__(self, dim: int = 384, hidden: int = HIDDEN, dropout: float = DROPOUT):
        super().__init__()
        self.dim, self.hidden = int(dim), int(hidden)
        self.net = nn.Sequential(nn.Dropout(dropout), nn.Linear(dim, hidden), nn.GELU(), nn.Dropout(dropout),
                                 nn.Linear(hidden, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x).squeeze(-1)


def embed_texts(texts: list[str], text_cache, batch: int = 256) -> torch.Tensor:
    """(N, dim) unit sentence embeddings of ``texts`` through a text cache (``get_or_compute``)."""
    out = []
    for a in range(0, len(texts), batch):
        tokens, mask = text_cache.get_or_compute(list(texts[a:a + batch]))
        out.append(sentence_embedding(tokens.float().cpu(), mask.bool().cpu()))
    return torch.cat(out) if out else torch.zeros(0, 384)


def train_classifier(inside: torch.Tensor, outside: torch.Tensor, *, hidden: int = HIDDEN, epochs: int = EPOCHS,
                     seed: int = 0, progress: bool = False) -> DomainClassifier:
    """Train on embeddings ``inside`` (label 1) against ``outside`` (label 0), the two classes weighted equally;
    deterministic for ``seed`` on one thread."""
    if len(inside) == 0 or len(outside) == 0:
        raise SMFError("the out-of-domain detector needs in-domain and foreign captions")
    gen = torch.Generator().manual_seed(seed)
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        clf = DomainClassifier(inside.shape[1], hidden)
        x = torch.cat([inside, outside]).float()
        y = torch.cat([torch.ones(len(inside)), torch.zeros(len(outside))])
        w = torch.where(y > 0, 0.5 / len(inside), 0.5 / len(outside)) * len(y)
        opt = torch.optim.AdamW(clf.parameters(), lr=LR, weight_decay=WEIGHT_DECAY)
        clf.train()
        for epoch in range(epochs):
            perm = torch.randperm(len(x), generator=gen)
            for a in range(0, len(x), BATCH):
                i = perm[a:a + BATCH]
                loss = (nn.functional.binary_cross_entropy_with_logits(clf(x[i]), y[i], reduction="none") * w[i]).mean()
                opt.zero_grad()
                loss.backward()
                opt.step()
            if progress:
                print(f"  detector epoch {epoch + 1}/{epochs}: loss {loss.item():.4f}", flush=True)
    return clf.eval()


class DomainDetector:
    """A trained :class:`DomainClassifier` with its calibration: ``score`` in (0, 1), out of domain below 0.5."""

    THRESHOLD = 0.5

    def __init__(self, classifier: DomainClassifier, offset: float, scale: float, encoder: str = "minilm"):
        self.classifier, self.offset, self.scale, self.encoder = classifier.eval(), float(offset), float(scale), encoder

    @torch.no_grad()
    def logits(self, embeddings: torch.Tensor) -> torch.Tensor:
        return self.classifier(embeddings.float())

    def scores(self, embeddings):
        """(B,) in-domain scores of unit sentence embeddings (B, dim): numpy in, numpy out; torch in, torch out."""
        return numpy_edge(self._scores)(embeddings)

    def _scores(self, embeddings: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid((self.logits(embeddings) - self.offset) / self.scale)

    @classmethod
    def calibrate(cls, classifier: DomainClassifier, heldout_inside: torch.Tensor, flag_rate: float = FLAG_RATE,
                  encoder: str = "minilm") -> "DomainDetector":
        """Offset at the ``flag_rate`` quantile of held-out in-domain logits, scale their spread (std)."""
        with torch.no_grad():
            z = classifier.eval()(heldout_inside.float())
        return cls(classifier, float(torch.quantile(z, flag_rate)), float(z.std().clamp(min=1e-3)), encoder)

    def save(self, path: str | Path) -> None:
        from safetensors.torch import save_file

        from ..core.io import atomic_path

        tensors = {k: v.detach().to(torch.float16).contiguous() for k, v in self.classifier.state_dict().items()}
        meta = {"dim": str(self.classifier.dim), "hidden": str(self.classifier.hidden), "offset": repr(self.offset),
                "scale": repr(self.scale), "encoder": self.encoder}
        with atomic_path(Path(path)) as tmp:
            save_file(tensors, str(tmp), metadata=meta)
            tmp.chmod(0o644)  # a release file, readable like the rest of the folder

    @classmethod
    def load(cls, path: str | Path) -> "DomainDetector":
        from safetensors import SafetensorError, safe_open

        path = Path(path)
        try:
            with safe_open(str(path), framework="pt", device="cpu") as f:
                meta = f.metadata() or {}
                state = {k: f.get_tensor(k).float() for k in f.keys()}
            clf = DomainClassifier(int(meta["dim"]), int(meta["hidden"]))
            clf.load_state_dict(state)
            return cls(clf, float(meta["offset"]), float(meta["scale"]), meta.get("encoder", "minilm"))
        except (OSError, KeyError, ValueError, RuntimeError, SafetensorError) as e:
            raise SMFError(f"{path}: not an out-of-domain detector ({e})") from None


# ------------------------------------------------------------------------------------------- the captions

def corpus_captions(root: str | Path, split: str = "train") -> list[str]:
    """The distinct captions of a corpus split (HumanML3D layout: ``texts/<id>.txt``), in file order."""
    from ..data.layout import MotionLayout

    layout = MotionLayout(root)
    seen: dict[str, None] = {}
    for mid in layout.ids(split):
        for line in layout.load_texts(mid):
            seen.setdefault(line.caption, None)
    return list(seen)


def lexicon_captions(lexicon: str = "bandai", per_pair: int = 48, *, heldout: bool = False, seed: str = "domain"
                     ) -> list[str]:
    """Distinct captions of every (content, style) pair of the lexicon's datasets from the caption grammar
    (training words, or held-out words with ``heldout``): the corpus's captions when no corpus is at hand."""
    from ..data.captions import captions_for
    from ..data.lexicon import load_lexicon

    lex = load_lexicon(lexicon)
    seen: dict[str, None] = {}
    for d, (contents, styles) in lex.datasets.items():
        for c in contents:
            for s in styles:
                for text, _ in captions_for(c, s, per_pair, seed=f"{seed}-{d}", heldout=heldout, lexicon=lexicon):
                    seen.setdefault(text, None)
    return list(seen)


def heldout_inside(lexicon: str = "bandai", per_pair: int | None = None) -> list[str]:
    """Held-out in-domain prompts the package can make itself: the lexicon's held-out phrasings as "a person
    ..." sentences and captions made only of held-out words (``per_pair`` per (content, style) pair)."""
    from ..data.lexicon import load_lexicon, person_sentence

    lex = load_lexicon(lexicon)
    phrasings = [person_sentence(p) for w in lex.contents.values() for p in w.heldout]
    per_pair = HELDOUT_PER_PAIR if per_pair is None else per_pair
    return phrasings + lexicon_captions(lexicon, per_pair, heldout=True, seed="ood-heldout")


def calibration_inside(lexicon: str = "bandai") -> list[str]:
    """The prompts the threshold is calibrated on: the lexicon's free-form in-domain prompts
    (``assets/lexicons/<lexicon>-calibration.txt``), or :func:`heldout_inside` for a lexicon without them."""
    from importlib import resources

    path = resources.files("stablemofusion") / "assets" / "lexicons" / CALIBRATION_FILE.format(lexicon=lexicon)
    if not path.is_file():
        return heldout_inside(lexicon)
    lines = path.read_text(encoding="utf-8").splitlines()
    return [x.strip() for x in lines if x.strip() and not x.lstrip().startswith("#")]


def build_detector(inside_captions: list[str], text_cache, *, lexicon: str = "bandai", flag_rate: float = FLAG_RATE,
                   seed: int = 0, encoder: str = "minilm", progress: bool = False) -> DomainDetector:
    """Train the classifier on ``inside_captions`` against the foreign captions and calibrate it on the
    lexicon's calibration prompts (:func:`calibration_inside`)."""
    from .foreign import foreign_captions

    if progress:
        print(f"out-of-domain detector: embedding {len(inside_captions)} in-domain captions", flush=True)
    inside = embed_texts(inside_captions, text_cache)
    outside = embed_texts(foreign_captions(FOREIGN_PER_PHRASE, lexicon=lexicon), text_cache)
    clf = train_classifier(inside, outside, seed=seed, progress=progress)
    return DomainDetector.calibrate(clf, embed_texts(calibration_inside(lexicon), text_cache), flag_rate, encoder)


def detector_entry(detector_file: str = DETECTOR_FILE) -> dict:
    """The ``detector`` block of ``actions.json`` naming the detector file beside it."""
    return {"file": detector_file, "about": "MLP on the sentence embedding, training captions vs foreign captions; "
                                            "similarity = its calibrated in-domain score, out of domain below 0.5"}


__all__ = ["DETECTOR_FILE", "FLAG_RATE", "DomainClassifier", "DomainDetector", "build_detector", "calibration_inside",
           "corpus_captions", "detector_entry", "embed_texts", "heldout_inside", "lexicon_captions", "train_classifier"]
