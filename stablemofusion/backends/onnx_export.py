"""Export a model folder's inference path as ONNX graphs for the ONNX backend (:mod:`stablemofusion.backends.onnx_backend`).

One folder (``graphs.json`` the manifest, docs/runtime.md the contract) holds every network the default path
runs; what is plain arithmetic (the sampler loops as coefficient tables, feature decoding, the rigid stage,
cleanup, the known actions' similarities) stays numpy, shared with the torch path:

- ``text_encoder.onnx``: MiniLM, ``input_ids``, ``attention_mask`` (B, L) int64 -> ``tokens`` (B, L, 384) (zero
  on padding), ``sentence`` (B, 384) the unit mean of the valid tokens; ``tokenizer.json`` its tokenizer
  (the ``tokenizers`` package); weights stored as float16, computed in float32 (the torch encoder rounds its
  weights the same way, :mod:`stablemofusion.text.frozen`);
- per model (the student at the top, its teacher in ``teacher/``): ``condition.onnx`` the text side (``tokens``,
  ``mask`` bool, and ``drop`` (B,) bool for a teacher or ``guidance`` (B,) float32 for a student -> ``features``
  (B, L, latent), ``sentence`` (B, C)); ``denoise.onnx`` one step (``x`` (B, T, D) with T a multiple of
  ``pad_multiple``, ``t`` (B,) float32, ``features``, ``text_mask`` bool, ``keep`` (B,) bool, ``sentence``,
  ``motion_mask`` (B, T) bool -> ``x0`` (B, T, D)); the sampler tables of every (sampler, steps) it takes;
- ``length.onnx`` (``tokens``, ``mask``, ``level`` (B,) -> ``frames`` (B,) int64, the length distribution's
  quantile at each level) and ``ood.onnx``
  (``sentence`` (B, 384) -> ``score`` (B,) in-domain score); the actions' example embeddings (``actions.npy``).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ..core.errors import SMFError
from ..footskate.cleanup import CleanupConfig, clean_joints, detect_contacts
from ..footskate.contacts import HML_FOOT_JOINTS, contacts_of_feet
from ..motion.features import joints_from_features
from ..motion.rigid import DEFAULT_FIT
from ..motion.bvh import BVH_ORDER
from ..motion.rigid_batch import fit_joints, pose_joints
from ..motion.rotation import matrix_to_euler
from ..core.edit_plan import continue_features
from ..core.path_plan import bend_features, follow_features

from .onnx_graphs import FORMAT, MANIFEST, TABLE_FIELDS, VERSION

OPSET = 18


class _TextEncoderGraph(nn.Module):
    def __init__(self, bert: nn.Module):
        super().__init__()
        self.bert = bert

    def forward(self, input_ids, attention_mask):
        from ..text.frozen import sentence_embedding

        hidden = self.bert(input_ids=input_ids, attention_mask=attention_mask).last_hidden_state
        mask = attention_mask.bool()
        tokens = hidden * mask[..., None].to(hidden.dtype)
        return tokens, sentence_embedding(tokens, mask)


class _ConditionGraph(nn.Module):
    def __init__(self, model, sentence: bool):
        super().__init__()
        self.model, self.sentence = model, sentence

    def forward(self, tokens, mask, control):
        if self.model.takes_guidance:  # a student: control is the guidance scale (B,)
            c = self.model.condition(tokens, mask, torch.zeros_like(mask[:, 0]), control)
        else:  # a teacher: control is the drop flag (B,)
            c = self.model.condition(tokens, mask, control)
        return (c.features, c.sentence) if self.sentence else c.features


class _DenoiseGraph(nn.Module):
    def __init__(self, model, sentence: bool):
        super().__init__()
        self.model, self.sentence = model, sentence

    def forward(self, x, t, features, text_mask, keep, a, b=None):
        from ..models.base import TextCondition

        sentence, motion_mask = (a, b) if self.sentence else (None, a)  # (sentence,) motion_mask
        return self.model.denoise(x, t, TextCondition(features, text_mask, keep, sentence), motion_mask)


class _LengthGraph(nn.Module):
    def __init__(self, estimator):
        super().__init__()
        self.estimator = estimator

    def forward(self, tokens, mask, level):
        return self.estimator.predict_frames(tokens, mask, level).long()


def export_length_graph(estimator, path: Path) -> None:
    """``length.onnx`` of a length estimator: ``tokens`` (B, L, C), ``mask`` (B, L), ``level`` (B,) float32 ->
    ``frames`` (B,) int64, each distribution's quantile at its level."""
    tokens, mask = torch.randn(2, 7, 384), torch.ones(2, 7, dtype=torch.bool)
    mask[1, 4:] = False
    _export(_LengthGraph(estimator.eval()), (tokens, mask, torch.tensor([0.5, 0.25])), path,
            ["tokens", "mask", "level"], ["frames"],
            {"tokens": {0: "B", 1: "L"}, "mask": {0: "B", 1: "L"}, "level": {0: "B"}, "frames": {0: "B"}})


class _OODGraph(nn.Module):
    def __init__(self, detector):
        super().__init__()
        self.classifier = detector.classifier
        self.offset, self.scale = float(detector.offset), float(detector.scale)

    def forward(self, sentence):
        return torch.sigmoid((self.classifier(sentence) - self.offset) / self.scale)


def _export(module: nn.Module, args: tuple, path: Path, inputs: list[str], outputs: list[str],
            dynamic: dict[str, dict[int, str]], fp16: str = "exact", multiples: dict[str, int] | None = None) -> None:
    """Export with torch.export (dynamic batch, text and motion lengths: ``dynamic`` input name -> {axis: name};
    ``multiples`` name -> m: that size is any multiple of m); ``fp16``: "exact" stores the initialisers float16
    holds exactly as float16, "all" every large one."""
    import onnx

    from ..text.transformer import no_fast_path

    dims = {name: torch.export.Dim(name, min=1, max=4096) for axes in dynamic.values() for name in axes.values()}
    for name, m in (multiples or {}).items():
        dims[name] = m * torch.export.Dim(name + "_units", min=1, max=4096 // m)
    shapes = tuple({axis: dims[name] for axis, name in dynamic.get(i, {}).items()} or None for i in inputs)
    import warnings

    module.eval()
    with torch.no_grad(), no_fast_path(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the exporter's notes on renamed axes and traced branches
        torch.onnx.export(module, args, str(path), input_names=inputs, output_names=outputs, dynamic_shapes=shapes,
                          opset_version=OPSET, dynamo=True, optimize=True, verbose=False, external_data=False)
    model = onnx.load(str(path))
    _store_fp16(model, exact=fp16 == "exact")
    onnx.save(model, str(path))


def _store_fp16(model, exact: bool) -> None:
    """Store large float32 initialisers as float16 with a Cast back to float32 (computed in float32): all of
    them (the text encoder's, which the torch encoder rounds the same way, FP16_MIN_ELEMENTS), or with ``exact``
    those that float16 holds exactly (a shipped model's weights are float16)."""
    from onnx import TensorProto, helper, numpy_helper

    from ..text.frozen import FP16_MIN_ELEMENTS

    graph = model.graph
    casts, keep = [], []
    for init in graph.initializer:
        arr = numpy_helper.to_array(init) if init.data_type == TensorProto.FLOAT else None
        if arr is not None and arr.size >= FP16_MIN_ELEMENTS and (
                not exact or np.array_equal(arr.astype(np.float16).astype(np.float32), arr)):
            half = numpy_helper.from_array(arr.astype(np.float16), init.name + "_fp16")
            keep.append(half)
            casts.append(helper.make_node("Cast", [half.name], [init.name], to=TensorProto.FLOAT))
        else:
            keep.append(init)
    del graph.initializer[:]
    graph.initializer.extend(keep)
    nodes = list(graph.node)
    del graph.node[:]
    graph.node.extend(casts + nodes)


def weight_map(state: dict[str, torch.Tensor], folder: Path, files: tuple[str, ...]) -> dict[str, list] | None:
    """Where each weight of ``state`` lies in the graphs ``files`` of ``folder``, so that the torch backend loads its
    weights from the graphs and a release holds one copy of them: name -> [file, initialiser, layout], layout '' (the
    initialiser's values in the weight's shape) or 'T' (its transpose). The exporter renames, reshapes and
    transposes some weights, so each is found by value, its own name tried first. None when a weight is held by
    no graph as such (the exporter folded it into another: a model folder keeps its weights file then)."""
    import onnx
    from onnx import numpy_helper

    inits = [(f, i.name, numpy_helper.to_array(i)) for f in files
             for i in onnx.load(str(folder / f)).graph.initializer]
    out = {}
    for key, value in state.items():
        want = value.detach().float().cpu().numpy()
        named = [r for r in inits if r[1] in (f"model.{key}", f"model.{key}_fp16")]
        hit = None
        for f, name, arr in named + [r for r in inits if r[2].size == want.size and r not in named]:
            arr = arr.astype(np.float32)
            if np.array_equal(arr.ravel(), want.ravel()):
                hit = [f, name, ""]
            elif want.ndim == 2 and np.array_equal(arr.ravel(), want.T.ravel()):
                hit = [f, name, "T"]
            if hit:
                break
        if hit is None:
            return None
        out[key] = hit + [list(want.shape)]
    return out


def _tables(sampler: str, steps_range: range, schedule, arrays: dict[str, np.ndarray]) -> dict:
    """The tables of one sampler for each step count it takes: their arrays into ``arrays`` (key
    ``sampler/steps/field``), returns {steps: {init_sigma, stochastic}}."""
    from ..diffusion.solvers import solver_table

    out = {}
    for k in steps_range:
        try:
            tab = solver_table(sampler, k, schedule)
        except SMFError:
            break
        for f in TABLE_FIELDS:
            arrays[f"{sampler}/{k}/{f}"] = getattr(tab, f).double().numpy()
        out[str(k)] = {"init_sigma": tab.init_sigma, "stochastic": tab.stochastic}
    return out


def export_model_graphs(components, out: Path) -> dict:
    """The condition and denoise graphs, the sampler tables and the settings of one loaded model
    (:class:`~stablemofusion.backends.torch_backend.TorchBackend`) into ``out``; returns its manifest entry."""
    from ..core.limits import LENGTH_MULTIPLE
    from ..diffusion.schedulers import parse_sampler, sampler_names

    model = components.model.float().eval()
    out.mkdir(parents=True, exist_ok=True)
    B, L, T, D = 2, 7, 48, int(components.mean.shape[0])
    tokens, mask = torch.randn(B, L, 384), torch.ones(B, L, dtype=torch.bool)
    mask[1, 5:] = False
    control = torch.full((B,), 2.5) if model.takes_guidance else torch.tensor([False, True])
    with torch.no_grad():
        c = model.condition(tokens, mask, torch.zeros(B, dtype=torch.bool), 2.5 if model.takes_guidance else None)
    has_sentence = c.sentence is not None  # the global condition (sentence embedding, a student's guidance)
    _export(_ConditionGraph(model, has_sentence), (tokens, mask, control), out / "condition.onnx",
            ["tokens", "mask", "guidance" if model.takes_guidance else "drop"],
            ["features", "sentence"][:1 + has_sentence],
            {"tokens": {0: "B", 1: "L"}, "mask": {0: "B", 1: "L"}, "guidance" if model.takes_guidance else "drop":
             {0: "B"}})
    motion_mask = torch.ones(B, T, dtype=torch.bool)
    motion_mask[1, 40:] = False
    text_inputs = ["features", "text_mask", "keep"] + ["sentence"] * has_sentence
    _export(_DenoiseGraph(model, has_sentence),
            (torch.randn(B, T, D), torch.tensor([999.0, 500.0]), c.features, c.mask, torch.ones(B, dtype=torch.bool))
            + ((c.sentence,) if has_sentence else ()) + (motion_mask,),
            out / "denoise.onnx", ["x", "t"] + text_inputs + ["motion_mask"], ["x0"],
            {"x": {0: "B", 1: "T"}, "t": {0: "B"}, "features": {0: "B", 1: "L"}, "text_mask": {0: "B", 1: "L"},
             "keep": {0: "B"}, "sentence": {0: "B"}, "motion_mask": {0: "B", 1: "T"}},
            multiples={"T": _pad_multiple(model)})
    np.save(out / "Mean.npy", components.mean.numpy().astype(np.float32))
    np.save(out / "Std.npy", components.std.numpy().astype(np.float32))
    settings = components.settings()
    samplers = [settings.sampler] if components.student else \
        [n for n in sampler_names() if parse_sampler(n)[1].fast and not parse_sampler(n)[0] == "lcm"]
    arrays: dict[str, np.ndarray] = {}
    tables = {s: _tables(s, range(1, components.max_steps + 1), components.schedule, arrays) for s in samplers}
    np.savez(out / "solvers.npz", **arrays)
    weights = weight_map(model.state_dict(), out, ("condition.onnx", "denoise.onnx"))
    cfg = components.config
    return {"student": bool(components.student), "sentence": has_sentence, "fps": cfg.fps, "min_frames": cfg.min_frames,
            "max_frames": cfg.max_frames, "length_multiple": LENGTH_MULTIPLE,
            "pad_multiple": _pad_multiple(model), "motion_dim": D,
            "skeleton": cfg.skeleton, "guidance": settings.guidance_scale, "sampler": settings.sampler,
            "steps": settings.steps, "max_steps": components.max_steps, "text_encoder": cfg.text_encoder,
            "files": {"condition": "condition.onnx", "denoise": "denoise.onnx", "mean": "Mean.npy", "std": "Std.npy",
                      "solvers": "solvers.npz"},
            "solvers": tables,
            **({"weights": weights} if weights is not None else {})}


def export_text_encoder(out: Path) -> dict:
    """MiniLM and its tokenizer into ``out`` (the encoder the shipped models use)."""
    from ..text.frozen import MiniLMEncoder, minilm_folder

    enc = MiniLMEncoder()
    ids = torch.tensor([[101, 1037, 2711, 10427, 102, 0], [101, 2619, 3216, 102, 0, 0]])
    am = (ids != 0).long()
    _export(_TextEncoderGraph(enc.model.float()), (ids, am), out / "text_encoder.onnx",
            ["input_ids", "attention_mask"], ["tokens", "sentence"],
            {"input_ids": {0: "B", 1: "L"}, "attention_mask": {0: "B", 1: "L"}, "tokens": {0: "B", 1: "L"},
             "sentence": {0: "B"}}, fp16="all")
    shutil.copyfile(minilm_folder() / "tokenizer.json", out / "tokenizer.json")
    return {"name": enc.name, "dim": enc.dim, "max_tokens": enc.max_tokens, "file": "text_encoder.onnx",
            "tokenizer": "tokenizer.json", "licence": "Apache-2.0 (sentence-transformers/all-MiniLM-L6-v2)"}


def export_onnx(model_path: str | Path | None, out: str | Path, *, text_encoder_from: str | Path | None = None,
                adapters=None) -> Path:
    """Every graph of a model folder (``None``: the shipped model) and its teacher into ``out`` (written
    atomically); returns ``out``. ``text_encoder_from``: a graphs folder whose text encoder and tokenizer are
    copied instead of exported again (the same MiniLM). ``adapters`` (``smf adapt`` files): merged into the
    weights first, their actions known: the graphs of the adapted model, as fast as the base's."""
    from ..core.io import atomic_dir
    from .torch_backend import TorchBackend
    from ..core.folders import model_folder

    path = model_folder(model_path)
    student = TorchBackend.from_pretrained(path, device="cpu", dtype=torch.float32, adapter=adapters or None)
    if student.config.text_encoder != "minilm":
        raise SMFError(f"only models on the MiniLM text encoder export to ONNX, this one uses "
                       f"{student.config.text_encoder}")
    with atomic_dir(Path(out)) as tmp:
        manifest = {"format": FORMAT, "version": VERSION, "noise_version": _noise_version()}
        if student.config.export is not None and student.config.export.version:
            manifest["model_version"] = student.config.export.version
        if student.adapters:
            manifest["adapters"] = list(student.adapters)
        if text_encoder_from is None:
            manifest["text_encoder"] = export_text_encoder(tmp)
        else:
            src = Path(text_encoder_from)
            entry = json.loads((src / MANIFEST).read_text(encoding="utf-8"))["text_encoder"]
            for f in (entry["file"], entry["tokenizer"]):
                shutil.copyfile(src / f, tmp / f)
            manifest["text_encoder"] = entry
        manifest["model"] = export_model_graphs(student, tmp)
        if student.student:
            teacher = TorchBackend.from_pretrained(path, teacher=True, device="cpu", dtype=torch.float32,
                                                 adapter=adapters or None)
            manifest["teacher"] = export_model_graphs(teacher, tmp / "teacher")
            manifest["teacher"]["folder"] = "teacher"
        if student.length_estimator is not None:
            est = student.length_estimator.eval()
            export_length_graph(est, tmp / "length.onnx")
            manifest["length"] = {"file": "length.onnx"}
        known = student.known_actions
        if known is not None:
            np.save(tmp / "actions.npy", known.examples_embedding().astype(np.float32))
            manifest["actions"] = {"threshold": known.threshold, "actions": known.actions, "top": known.top,
                                   "embeddings": "actions.npy"}
            if known.taught:  # adapters' actions: in domain close to one of their captions (text.known)
                from ..text.known import TAUGHT_SIMILARITY

                np.save(tmp / "taught.npy", known.embed([c for caps in known.taught.values() for c in caps]))
                manifest["actions"].update(taught=known.taught, taught_clips=known.taught_clips,
                                           taught_embeddings="taught.npy", taught_similarity=TAUGHT_SIMILARITY)
            if known.detector is not None:
                _export(_OODGraph(known.detector), (torch.randn(3, 384),), tmp / "ood.onnx", ["sentence"], ["score"],
                        {"sentence": {0: "B"}, "score": {0: "B"}})
                manifest["actions"]["detector"] = "ood.onnx"
        (tmp / MANIFEST).write_text(json.dumps(manifest, indent=1) + "\n", encoding="utf-8")
        (tmp / "README.md").write_text(_readme(path, manifest), encoding="utf-8")
    return Path(out)


def _readme(model: Path, manifest: dict) -> str:
    """The folder's note: what it holds and under which licences."""
    card = model / "MODEL_CARD.md"
    licence = ("the model's own: CC BY-NC 4.0 (non-commercial), trained on the Bandai-Namco Research Motion Dataset; "
               "see its MODEL_CARD.md" if card.is_file() and "CC BY-NC 4.0" in card.read_text(encoding="utf-8")
               else "the model's own (see its folder)")
    adapted = (f" with the adapters {', '.join(manifest['adapters'])} merged into its weights (their clips' licences: "
               "`smf info --adapter FILE`)") if manifest.get("adapters") else ""
    return (f"# Portable graphs of {model.name}{adapted}\n\n"
            "ONNX graphs of every network the model's default path runs, for the torch-free runtime "
            "(`smf generate --engine onnx`; inputs and outputs: docs/runtime.md). `graphs.json` lists them.\n\n"
            f"- `{manifest['text_encoder']['file']}`, `{manifest['text_encoder']['tokenizer']}`: all-MiniLM-L6-v2 "
            f"({manifest['text_encoder']['licence']}; weights stored as float16).\n"
            f"- every other file: the model's networks and tables; licence {licence}.\n")


def _noise_version() -> int:
    from ..core.noise import NOISE_VERSION

    return NOISE_VERSION


__all__ = ["MANIFEST", "export_onnx", "export_model_graphs", "export_text_encoder", "weight_map"]


def _pad_multiple(model) -> int:
    """The frame count the denoiser's input must be a multiple of (a UNet's levels halve it), else 1."""
    return int(getattr(model.config, "pad_multiple", 1))


class _ContactsGraph(nn.Module):
    def __init__(self, fps: float, config):
        super().__init__()
        self.fps, self.config = fps, config

    def forward(self, joints):
        return contacts_of_feet(joints[:, :, list(HML_FOOT_JOINTS)], self.fps, self.config)


class _CleanupGraph(nn.Module):
    def __init__(self, fps: float, config):
        super().__init__()
        self.fps, self.config = fps, config

    def forward(self, joints, bone_lengths):
        contacts = detect_contacts(joints, self.fps, self.config)
        cleaned, held = clean_joints(joints, contacts, bone_lengths, self.fps, self.config)
        return cleaned, held


class _RigidGraph(nn.Module):
    def __init__(self, sweeps: int):
        super().__init__()
        self.sweeps = sweeps

    def forward(self, features, bone_lengths):
        return fit_joints(joints_from_features(features, finite_check=False), bone_lengths, self.sweeps)


class _BendGraph(nn.Module):
    def __init__(self, fps: float):
        super().__init__()
        self.fps = fps

    def forward(self, features, kind, angle):
        return bend_features(features, kind, angle, self.fps, finite_check=False)


class _FollowGraph(nn.Module):
    def __init__(self, fps: float):
        super().__init__()
        self.fps = fps

    def forward(self, features, points, times, timed):
        return follow_features(features, points, times, timed, self.fps, finite_check=False)


class _ContinueGraph(nn.Module):
    def forward(self, features, known, keep):
        return continue_features(features, known, keep)


class _PoseGraph(nn.Module):
    def forward(self, joints, bone_lengths):
        offsets, local = pose_joints(joints, bone_lengths)
        return offsets, local, matrix_to_euler(local, BVH_ORDER)


FINAL_STAGE_GRAPHS = ("rigid.onnx", "bend.onnx", "follow.onnx", "contacts.onnx", "cleanup.onnx", "pose.onnx",
                      "continue.onnx")
MIN_GRAPH_FRAMES = 4  # the graphs' shortest motion (the lean needs 3 frames; a model's shortest is 40)


def export_final_stage(out: Path, fps: float = 20.0) -> list[Path]:
    """Export the final stage, as the Python runtimes run it, as float64 graphs in ``out`` (B motions of T frames):

    - ``rigid.onnx``: ``features`` (B, T, 263) raw HumanML3D features (dataset units), ``bone_lengths`` (B, 22)
      metres -> ``joints`` (B, T, 22, 3) metres: decoded, then one skeleton of those bone lengths fitted to them
      (:func:`~stablemofusion.motion.rigid_batch.fit_joints`, the default sweeps);
    - ``bend.onnx``: ``features``, ``kind`` (B,) int64 (an index into :data:`~stablemofusion.core.path_plan.KINDS`),
      ``angle`` (B,) radians -> ``features`` bent to the path words' path
      (:func:`~stablemofusion.core.path_plan.bend_features`);
    - ``follow.onnx``: ``features``, ``points`` (B, K, 2) metres, ``times`` (B, K) seconds, ``timed`` (B,) bool ->
      ``features`` whose root follows the points, the ``start`` facing (B,) radians and ``origin`` (B, 2) metres
      that place the finished motion on them (:func:`~stablemofusion.core.path_plan.follow_features`);
    - ``contacts.onnx``: ``joints`` (B, T, 22, 3) metres -> ``contacts`` (B, T, 4) bool, the cleanup's kinematic
      contacts (:func:`~stablemofusion.footskate.contacts.contacts_of_feet`);
    - ``cleanup.onnx``: ``joints`` (B, T, 22, 3) rigid, ``bone_lengths`` (B, 22) metres -> ``joints`` cleaned and
      ``held`` (B, T, 4) bool (:func:`~stablemofusion.footskate.cleanup.clean_joints` with the default settings);
    - ``pose.onnx``: ``joints`` (B, T, 22, 3) rigid, ``bone_lengths`` (B, 22) -> the skeleton's rest ``offsets``
      (B, 22, 3) metres, each joint's ``rotations`` (B, T, 22, 3, 3) in its parent's frame and the same as BVH
      channel angles ``euler`` (B, T, 22, 3) degrees, order BVH_ORDER (:func:`~stablemofusion.motion.rigid_batch.
      pose_joints`, :func:`~stablemofusion.motion.rotation.matrix_to_euler`);
    - ``continue.onnx``: ``features`` (B, T, 263) a timeline window's raw features, ``known`` (B, T, 263) the
      motion's last K frames first, ``keep`` (1,) int64 K (2 to T - 2) -> ``features`` whose first K frames are
      those and whose next ones are blended into them (:func:`~stablemofusion.core.edit_plan.continue_features`).

    Each is the Python function itself, traced (they are written against the array API, loop-free)."""
    import warnings

    import onnx

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    config = CleanupConfig()
    T = 60
    joints = torch.zeros(2, T, 22, 3, dtype=torch.float64)
    joints[..., 1] = torch.linspace(0.0, 1.6, 22, dtype=torch.float64)
    lengths = torch.full((2, 22), 0.1, dtype=torch.float64)
    features = torch.randn(2, T, 263, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 0.1
    kind, angle = torch.tensor([0, 1]), torch.tensor([1.0, -2.0], dtype=torch.float64)
    points = torch.tensor([[[0.0, 0.0], [0.0, 3.0], [3.0, 3.0]]] * 2, dtype=torch.float64)
    times, timed = torch.tensor([[0.0, 1.0, 2.5]] * 2, dtype=torch.float64), torch.tensor([False, True])
    batch = torch.export.Dim("batch", min=1, max=4096)
    knots = torch.export.Dim("points", min=2, max=100_000)
    frames = torch.export.Dim("frames", min=MIN_GRAPH_FRAMES, max=100_000)
    motion, per = {0: batch, 1: frames}, {0: batch}
    paths = []
    for name, module, args, inputs, outputs, shapes in (
            ("rigid.onnx", _RigidGraph(DEFAULT_FIT.iterations), (features, lengths), ["features", "bone_lengths"],
             ["joints"], (motion, per)),
            ("bend.onnx", _BendGraph(fps), (features, kind, angle), ["features", "kind", "angle"], ["features_out"],
             (motion, per, per)),
            ("follow.onnx", _FollowGraph(fps), (features, points, times, timed), ["features", "points", "times", "timed"],
             ["features_out", "start", "origin"], (motion, {0: batch, 1: knots}, {0: batch, 1: knots}, per)),
            ("contacts.onnx", _ContactsGraph(fps, config.kinematic), (joints,), ["joints"], ["contacts"], (motion,)),
            ("cleanup.onnx", _CleanupGraph(fps, config), (joints, lengths), ["joints", "bone_lengths"],
             ["joints_out", "held"], (motion, per)),
            ("pose.onnx", _PoseGraph(), (joints, lengths), ["joints", "bone_lengths"], ["offsets", "rotations", "euler"],
             (motion, per)),
            ("continue.onnx", _ContinueGraph(), (features, features.flip(1), torch.tensor([20])),
             ["features", "known", "keep"], ["features_out"], (motion, motion, None))):
        with torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(module.eval(), args, str(out / name), input_names=inputs, output_names=outputs,
                              dynamic_shapes=shapes, opset_version=OPSET, dynamo=True, optimize=True, verbose=False,
                              external_data=False)
        model = onnx.load(str(out / name))
        for node in model.graph.node:  # the exporter's notes on where each node came from: 90% of the file
            del node.metadata_props[:]
            node.doc_string = ""
        onnx.save(model, str(out / name))
        paths.append(out / name)
    return paths
