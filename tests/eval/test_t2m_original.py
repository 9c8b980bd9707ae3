"""Original T2M evaluator loader: synthetic checkpoints and GloVe files written in the official layout."""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch

from stablemofusion.core.errors import SMFError
from stablemofusion.eval.t2m_original import (POS_CLASSES, MovementConvEncoder, T2MOriginalEvaluator,
                                              WordVectorizer, _load_part, official_paths, read_humanml_tokens)

VOCAB = ["unk", "sos", "eos", "a", "man", "kick", "left", "leg", "walk", "person", "forward", "slowly", "the",
         "with", "his", "chair", "foot"]
ROLES = ("checkpoint", "mean", "std", "our_vab_data.npy", "our_vab_words.pkl", "our_vab_idx.pkl")


def write_glove(folder: Path, words: list[str], seed: int = 0) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    np.save(folder / "our_vab_data.npy", rng.standard_normal((len(words), 300)).astype(np.float32))
    with open(folder / "our_vab_words.pkl", "wb") as f:
        pickle.dump(list(words), f)
    with open(folder / "our_vab_idx.pkl", "wb") as f:
        pickle.dump({w: i for i, w in enumerate(words)}, f)


def write_official(root: Path, glove: Path, mean: np.ndarray, std: np.ndarray, seed: int = 0) -> dict:
    """An official-format tree with random weights; returns the saved checkpoint dict."""
    torch.manual_seed(seed)
    model = T2MOriginalEvaluator("t2m")
    ckpt = {k: getattr(model, k).state_dict() for k in ("text_encoder", "motion_encoder", "movement_encoder")}
    ckpt.update(epoch=7, iter=1234)  # the official file also holds bookkeeping entries
    (root / "t2m/text_mot_match/model").mkdir(parents=True)
    torch.save(ckpt, root / "t2m/text_mot_match/model/finest.tar")
    (root / "t2m/Comp_v6_KLD01/meta").mkdir(parents=True)
    np.save(root / "t2m/Comp_v6_KLD01/meta/mean.npy", mean)
    np.save(root / "t2m/Comp_v6_KLD01/meta/std.npy", std)
    write_glove(glove, VOCAB, seed)
    return ckpt


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """Small GRU batches: one intra-op thread is faster, and far cheaper on a busy machine."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def official(one_thread, tmp_path_factory) -> tuple[Path, Path, dict]:
    base = tmp_path_factory.mktemp("t2m_official")
    rng = np.random.default_rng(1)
    mean = rng.standard_normal(263).astype(np.float32)
    std = (0.5 + rng.random(263)).astype(np.float32)
    ckpt = write_official(base / "checkpoints", base / "glove", mean, std)
    return base / "checkpoints", base / "glove", ckpt


@pytest.fixture(scope="module")
def evaluator(official) -> T2MOriginalEvaluator:
    root, glove, _ = official
    return T2MOriginalEvaluator.from_files(root, glove, dataset="t2m")


def test_loads_strictly_with_official_weights(official, evaluator):
    _, _, ckpt = official
    assert not evaluator.training
    for key in ("text_encoder", "motion_encoder", "movement_encoder"):
        module = getattr(evaluator, key)
        assert set(module.state_dict()) == set(ckpt[key])
        module.load_state_dict(ckpt[key], strict=True)
        for name, value in module.state_dict().items():
            assert torch.equal(value, ckpt[key][name]), f"{key}.{name}"
    # the names the official code uses
    assert "hidden" in ckpt["motion_encoder"] and "gru.weight_hh_l0_reverse" in ckpt["motion_encoder"]
    assert ckpt["movement_encoder"]["main.0.weight"].shape == (512, 259, 4)
    assert ckpt["text_encoder"]["pos_emb.weight"].shape == (300, 15)


def test_motion_embedding_shape_determinism_and_padding(evaluator):
    g = torch.Generator().manual_seed(0)
    x = torch.randn(3, 24, 263, generator=g)
    lengths = [16, 8, 14]  # 14 is cut to 12 as in the official loader
    e1 = evaluator.embed_motion(x, lengths)
    assert e1.shape == (3, 512) and torch.isfinite(e1).all()
    assert torch.equal(evaluator.embed_motion(x, torch.tensor(lengths)), e1)
    assert not torch.allclose(e1[0], e1[1])
    # garbage (huge values, NaN) past each length, another batch order and another T: same embeddings
    order = [2, 0, 1]
    y = x[order, :16].clone()
    y[0, 12:] = float("nan")
    y[2, 8:] = 1e6
    e2 = evaluator.embed_motion(y, [lengths[i] for i in order])
    assert torch.allclose(e2, e1[order], atol=1e-5)


class Captured(Exception):
    """Stops embed_motion after the movement encoder (the costly 1024-wide GRU is not needed here)."""


def movements_of(evaluator, monkeypatch, x, lengths) -> tuple[torch.Tensor, torch.Tensor]:
    def capture(movements, steps):
        raise Captured(movements.clone(), steps.clone())

    monkeypatch.setattr(evaluator.motion_encoder, "forward", capture)
    try:
        evaluator.embed_motion(x, lengths)
    except Captured as c:
        return c.args
    finally:
        monkeypatch.undo()
    raise AssertionError("motion encoder not reached")


def test_motion_padding_follows_the_official_196_frames(evaluator, monkeypatch):
    """Official loader: motions zero-padded to 196 frames, so 196 frames see no zero tail, shorter ones do."""
    x = torch.randn(2, 240, 263, generator=torch.Generator().manual_seed(1))
    m, steps = movements_of(evaluator, monkeypatch, x, [196, 203])  # 203 -> 200 frames, 50 steps
    assert steps.tolist() == [49, 50]
    alone, _ = movements_of(evaluator, monkeypatch, x[:1, :196], [196])
    assert torch.allclose(m[0, :49], alone[0, :49], atol=1e-5)
    # with a zero tail (what a naive batch padding would give) the last step differs: the tail matters
    z = ((x[:1, :196] - evaluator.mean) / evaluator.std)[..., :-4]
    with torch.no_grad():
        with_tail = evaluator.movement_encoder(torch.nn.functional.pad(z, (0, 0, 0, 4)))
        no_tail = evaluator.movement_encoder(z)
    assert torch.allclose(no_tail[0], alone[0, :49], atol=1e-5)
    assert not torch.allclose(with_tail[0, 48], no_tail[0, 48], atol=1e-4)
    short, _ = movements_of(evaluator, monkeypatch, x[:1, :100], [100])
    long, _ = movements_of(evaluator, monkeypatch, x[:1], [100])
    assert torch.allclose(short[0, :25], long[0, :25], atol=1e-5)
    assert short.shape[1] == 49  # always at least the official 196 frames


def test_motion_input_checks(evaluator):
    with pytest.raises(SMFError, match="263"):
        evaluator.embed_motion(torch.zeros(1, 16, 251), [16])
    with pytest.raises(SMFError, match="lengths"):
        evaluator.embed_motion(torch.zeros(1, 16, 263), [3])
    with pytest.raises(SMFError, match="lengths"):
        evaluator.embed_motion(torch.zeros(1, 16, 263), [20])


def test_text_embedding(evaluator):
    toks = [["a/DET", "man/NOUN", "kick/VERB", "with/ADP", "his/DET", "left/ADJ", "leg/NOUN"],
            ["the/DET", "person/NOUN", "walk/VERB", "forward/ADV", "slowly/ADV"],
            ["zzz/NOUN"]]
    e = evaluator.embed_text(toks)
    assert e.shape == (3, 512) and torch.isfinite(e).all()
    assert torch.equal(e, evaluator.embed_tokens(toks))
    for i, t in enumerate(toks):  # batch padding does not leak into shorter captions
        assert torch.allclose(evaluator.embed_tokens([t])[0], e[i], atol=1e-5)
    # one space-separated string (a HumanML3D texts line's 2nd field) is the same as its token list
    assert torch.allclose(evaluator.embed_tokens([" ".join(toks[0])]), e[:1], atol=1e-6)
    # tokens beyond 20 are dropped
    long = ["walk/VERB"] * 20
    assert torch.allclose(evaluator.embed_tokens([long + ["chair/NOUN"] * 5]), evaluator.embed_tokens([long]))


def test_word_vectorizer_pos_and_vip(official):
    _, glove, _ = official
    wv = WordVectorizer.from_dir(glove)
    vectors = np.load(glove / "our_vab_data.npy")

    def cls(token: str) -> str:
        return POS_CLASSES[int(np.argmax(wv[token][1]))]

    assert cls("man/NOUN") == "NOUN" and cls("a/DET") == "DET"
    assert cls("left/ADJ") == "Loc_VIP" and cls("forward/ADV") == "Loc_VIP"
    assert cls("leg/NOUN") == "Body_VIP" and cls("foot/NOUN") == "Body_VIP"
    assert cls("chair/NOUN") == "Obj_VIP"
    assert cls("kick/VERB") == "Act_VIP" and cls("walk/NOUN") == "Act_VIP"
    assert cls("slowly/ADV") == "Desc_VIP"
    assert cls("with/CCONJ") == "OTHER" and cls("sos/OTHER") == "OTHER"
    # out of vocabulary: the 'unk' vector and OTHER, whatever the tag or VIP list says
    vec, pos = wv["jump/VERB"]
    assert np.array_equal(vec, vectors[VOCAB.index("unk")]) and POS_CLASSES[int(np.argmax(pos))] == "OTHER"
    assert np.array_equal(wv["man/NOUN"][0], vectors[VOCAB.index("man")])
    assert wv["man/NOUN"][1].sum() == 1.0 and wv["man/NOUN"][1].shape == (15,)
    words, pos, lengths = wv.batch([["man/NOUN"], ["a/DET"] * 30])
    assert words.shape == (2, 22, 300) and pos.shape == (2, 22, 15) and lengths.tolist() == [3, 22]
    assert POS_CLASSES[int(pos[0, 3].argmax())] == "OTHER"  # unk/OTHER padding


def test_untagged_text_is_a_clear_error(evaluator):
    with pytest.raises(SMFError, match="POS-tagged"):
        evaluator.embed_captions(["a man walks forward"])
    with pytest.raises(SMFError, match="word/POS|POS-tagged"):
        evaluator.embed_tokens([["a", "man"]])


@pytest.mark.parametrize("role", ROLES)
def test_each_missing_file_is_named(official, tmp_path, role):
    root, glove, _ = official
    src = official_paths(root, glove)
    new_root, new_glove = tmp_path / "checkpoints", tmp_path / "glove"
    dst = official_paths(new_root, new_glove)
    for r, p in src.items():
        if r != role:
            dst[r].parent.mkdir(parents=True, exist_ok=True)
            os.symlink(p, dst[r])
    with pytest.raises(SMFError) as e:
        T2MOriginalEvaluator.from_files(new_root, new_glove)
    msg = str(e.value)
    assert str(dst[role]) in msg and "\n" not in msg


def test_wrong_dataset_key_and_shape(official, tmp_path):
    root, glove, ckpt = official
    with pytest.raises(SMFError, match="dataset"):
        T2MOriginalEvaluator.from_files(root, glove, dataset="humanml")
    # a KIT tree holding HumanML3D-sized meta files: shape error naming the file
    kit_meta = tmp_path / "kit/Comp_v6_KLD005/meta"
    kit_meta.mkdir(parents=True)
    (tmp_path / "kit/text_mot_match/model").mkdir(parents=True)
    os.symlink(root / "t2m/text_mot_match/model/finest.tar", tmp_path / "kit/text_mot_match/model/finest.tar")
    for n in ("mean.npy", "std.npy"):
        os.symlink(root / "t2m/Comp_v6_KLD01/meta" / n, kit_meta / n)
    with pytest.raises(SMFError, match=r"mean\.npy.*\(251,\)"):
        T2MOriginalEvaluator.from_files(tmp_path, glove, dataset="kit")
    # a checkpoint without one of the three state dicts
    bad = tmp_path / "bad"
    (bad / "t2m/text_mot_match/model").mkdir(parents=True)
    torch.save({"text_encoder": ckpt["text_encoder"]}, bad / "t2m/text_mot_match/model/finest.tar")
    os.symlink(root / "t2m/Comp_v6_KLD01", bad / "t2m/Comp_v6_KLD01")
    with pytest.raises(SMFError, match="motion_encoder") as e:
        T2MOriginalEvaluator.from_files(bad, glove)
    assert "\n" not in str(e.value)
    # a state dict with a wrong tensor shape
    enc = MovementConvEncoder(259)
    state = dict(enc.state_dict())
    state["out_net.weight"] = torch.zeros(512, 256)
    with pytest.raises(SMFError, match=r"out_net\.weight has shape \(512, 256\)"):
        _load_part(enc, {"movement_encoder": state}, "movement_encoder", Path("finest.tar"))


def test_real_humanml3d_reference(hml_ref, official, tmp_path):
    """End to end on a real HumanML3D motion and its real word/POS captions (synthetic weights)."""
    root, glove, _ = official
    new_root = tmp_path / "checkpoints"
    (new_root / "t2m").mkdir(parents=True)
    os.symlink(root / "t2m/text_mot_match", new_root / "t2m/text_mot_match")
    meta = new_root / "t2m/Comp_v6_KLD01/meta"
    meta.mkdir(parents=True)  # the dataset's own statistics stand in for the evaluator's meta files
    np.save(meta / "mean.npy", np.load(hml_ref / "Mean.npy"))
    np.save(meta / "std.npy", np.load(hml_ref / "Std.npy"))
    ev = T2MOriginalEvaluator.from_files(new_root, glove)
    motion = np.load(hml_ref / "new_joint_vecs" / "000000.npy")  # (116, 263), float64
    em = ev.embed_motion(torch.from_numpy(motion)[None], [len(motion)])
    assert em.shape == (1, 512) and torch.isfinite(em).all()
    caps = read_humanml_tokens(hml_ref / "texts" / "000000.txt")
    assert len(caps) == 4 and caps[0][:3] == ["a/DET", "man/NOUN", "kick/VERB"]
    et = ev.embed_tokens(caps)
    assert et.shape == (4, 512) and torch.isfinite(et).all()
    dist = torch.cdist(em, et)
    assert dist.shape == (1, 4) and (dist > 0).all()


def test_kit_sizes():
    ev = T2MOriginalEvaluator("kit").eval()
    assert ev.movement_encoder.main[0].weight.shape == (512, 247, 4) and ev.mean.shape == (251,)
    x = torch.randn(1, 12, 251, generator=torch.Generator().manual_seed(2))
    assert ev.embed_motion(x, [12]).shape == (1, 512)
    with pytest.raises(SMFError, match="251"):
        ev.embed_motion(torch.zeros(1, 12, 263), [12])
