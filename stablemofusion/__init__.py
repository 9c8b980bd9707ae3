"""stablemofusion: text-to-human-motion generation with the StableMoFusion design.

``from stablemofusion import MotionPipeline`` (imported on first use, so ``smf --version`` stays fast): on the
torch backend where PyTorch is installed, else on the exported graphs with ONNX Runtime.
"""

__version__ = "0.4.8"  # CHANGELOG.md: what each version changed
__all__ = ["MotionPipeline", "MotionResult", "RigidMotion", "__version__"]


def __getattr__(name: str):
    if name in ("MotionPipeline", "MotionResult"):
        from .pipelines import motion_pipeline

        return getattr(motion_pipeline, name)
    if name == "RigidMotion":
        from .motion.rigid import RigidMotion

        return RigidMotion
    raise AttributeError(f"module 'stablemofusion' has no attribute {name!r}")
