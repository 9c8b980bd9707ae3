"""Shared fixtures: paths to the read-only ../shared data (absent on a user's fresh machine)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"
HML_REF = SHARED / "humanml3d-reference"
BANDAI_ARCHIVE = SHARED / "bandai-namco-motion.tar.xz"


def need(path: Path) -> Path:
    """Skip the test with a clear reason when shared data is missing."""
    if not path.exists():
        pytest.skip(f"shared data not found at {path} (only present in CI and developer checkouts)")
    return path


@pytest.fixture(scope="session")
def hml_ref() -> Path:
    return need(HML_REF)


@pytest.fixture(scope="session", params=["000000", "012314"])
def ref_motion(request, hml_ref) -> tuple[str, np.ndarray, np.ndarray]:
    """(id, new_joints (T, 22, 3), new_joint_vecs (T, 263)) of a reference HumanML3D motion."""
    mid = request.param
    return mid, np.load(hml_ref / "new_joints" / f"{mid}.npy"), np.load(hml_ref / "new_joint_vecs" / f"{mid}.npy")


# A handful of real Bandai-Namco clips in the archive's own folder layout (labels included).
BANDAI_MINI = (
    "dataset-1_walk_normal_001", "dataset-1_walk_normal_002", "dataset-1_run_normal_001", "dataset-1_dash_normal_001",
    "dataset-2_walk-turn-left_normal_001", "dataset-2_walk-turn-left_normal_002", "dataset-2_wave-left-hand_active_001",
)


@pytest.fixture(scope="session")
def bandai_mini_source(tmp_path_factory) -> Path:
    """Unpack the label files and the BANDAI_MINI clips (one streaming pass over the archive, ~10 s)."""
    import tarfile

    need(BANDAI_ARCHIVE)
    out = tmp_path_factory.mktemp("bandai-mini")
    wanted = {f"{n}.{ext}" for n in BANDAI_MINI for ext in ("bvh", "json")}
    with tarfile.open(BANDAI_ARCHIVE, "r|xz") as tar:
        for member in tar:
            name = member.name.rsplit("/", 1)[-1]
            if member.isfile() and (name in wanted or "/cfg/" in member.name):
                tar.extract(member, out, filter="data")
    return out


@pytest.fixture(scope="session")
def bandai_mini_corpus(bandai_mini_source, tmp_path_factory) -> Path:
    """The mini Bandai-Namco corpus in the HumanML3D layout (built once; tests must not modify it)."""
    from stablemofusion.data.corpus_bandai import build_corpus

    out = tmp_path_factory.mktemp("bandai-mini-corpus")
    build_corpus(bandai_mini_source, out, workers=1)
    return out


@pytest.fixture(scope="session")
def save_tiny_checkpoint():
    """The function below, for tests in any folder."""
    return _save_tiny_checkpoint


def _save_tiny_checkpoint(path: Path, mean: np.ndarray, std: np.ndarray) -> Path:
    """A 'tiny' denoiser (8 channels per norm group) with random non-zero weights everywhere, saved like a
    trained checkpoint at ``path``."""
    import torch

    from stablemofusion.diffusion.checkpoint import save_checkpoint
    from stablemofusion.diffusion.config import CheckpointConfig
    from stablemofusion.models.registry import build_denoiser
    from stablemofusion.models.presets import get_preset

    torch.manual_seed(0)
    cfg = get_preset("tiny")
    cfg.options.update(base_dim=32, groups=4)  # well-conditioned numerics
    model = build_denoiser(cfg)
    with torch.no_grad():
        for p in model.parameters():
            if p.abs().sum() == 0:
                p.normal_(0, 0.02)
    save_checkpoint(path, model=model, mean=mean, std=std, ema_state=model.state_dict(),
                    config=CheckpointConfig.for_skeleton(cfg, "humanml3d"))
    return path


@pytest.fixture(scope="session")
def tiny_checkpoint(tmp_path_factory) -> Path:
    """One tiny random-weight checkpoint (root height 0.9 m on average) shared by the tests that only read it."""
    mean, std = np.zeros(263), np.full(263, 0.1)
    mean[3] = 0.9
    return _save_tiny_checkpoint(tmp_path_factory.mktemp("tiny-ckpt") / "checkpoint", mean, std)


@pytest.fixture(scope="module")
def checkpoint(tiny_checkpoint) -> Path:
    """The tiny checkpoint, for the modules that do not define a ``checkpoint`` of their own."""
    return tiny_checkpoint


@pytest.fixture(scope="module")
def pipe(checkpoint):
    """A pipeline of ``checkpoint`` on one thread, one per module (tests may change it)."""
    import torch

    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    torch.set_num_threads(1)
    return MotionPipeline.from_pretrained(checkpoint, device="cpu")


@pytest.fixture(scope="session")
def save_tiny_student():
    """The function below, for tests in any folder."""
    return _save_tiny_student


def _save_tiny_student(path: Path, teacher: Path, name: str | None = None, sample_steps: int = 1) -> Path:
    """A distilled student of the checkpoint ``teacher`` (its weights plus the zero-initialised guidance input,
    not trained), saved at ``path``; its ``distil.teacher`` is ``name`` (default: ``teacher`` as given)."""
    from dataclasses import replace

    from stablemofusion.diffusion.checkpoint import load_checkpoint, save_checkpoint
    from stablemofusion.diffusion.config import DistilConfig
    from stablemofusion.diffusion.distil import student_from_teacher

    ck = load_checkpoint(teacher)
    config = replace(ck.config, model=replace(ck.config.model, guidance=True), guidance=None,
                     distil=DistilConfig(teacher=str(teacher) if name is None else name, sample_steps=sample_steps))
    save_checkpoint(path, model=student_from_teacher(ck), config=config, mean=ck.mean, std=ck.std)
    return path


@pytest.fixture(scope="session")
def save_random_adapter():
    """The function below, for tests in any folder."""
    return _save_random_adapter


def _save_random_adapter(path: Path, checkpoint: Path, name: str = "kick", seed: int = 1) -> Path:
    """An adapter file of random low-rank updates (rank 2) for the (non-student) ``checkpoint``, saved at ``path``:
    it fits that model and changes its motions; its action ``name`` has the caption "a person <name>s"."""
    import torch

    from stablemofusion.adapters.file import Adapter, AdapterInfo, weights_hash
    from stablemofusion.adapters.lora import LoraConfig, add_lora, lora_state
    from stablemofusion.diffusion.checkpoint import load_checkpoint

    model = load_checkpoint(checkpoint).model
    add_lora(model, LoraConfig(rank=2))
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for n, p in model.named_parameters():
            if "lora_" in n:
                p.copy_(torch.randn(p.shape, generator=g) * 0.05)
    info = AdapterInfo(name=name, actions={name: [f"a person {name}s"]}, clips=[(f"{name}_01.bvh", f"a person {name}s")],
                       licence="CC BY 4.0", base={"student": "0" * 64, "teacher": weights_hash(checkpoint)},
                       lora=LoraConfig(rank=2), guidance=2.5, training={"seconds": 1.0})
    return Adapter(info, {"student": {}, "teacher": lora_state(model)}).save(path)


@pytest.fixture(scope="session")
def blender_shares_python():
    """Skip unless Debian's `blender` is installed and runs this Python's minor version (the add-on then imports
    the packages of this test environment in Blender's own Python)."""
    import shutil
    import subprocess
    import sys

    if shutil.which("blender") is None:
        pytest.skip("blender is not installed (Debian: apt-get install blender python3-numpy; .ci/run does)")
    version = subprocess.run(["blender", "-b", "--factory-startup", "--python-expr",
                              "import sys; print('PYTHON', sys.version_info[:2])"], capture_output=True, text=True,
                             timeout=300).stdout
    if f"PYTHON {tuple(sys.version_info[:2])}" not in version:
        pytest.skip(f"Blender's Python is not this Python {sys.version_info[:2]}: its packages cannot be shared")
