"""Task pipelines (diffusers style: one per task, each ``__call__`` a numbered script from checking inputs to
post-processing), each written once against the backend seam (:mod:`stablemofusion.backends.base`), with one
:class:`~stablemofusion.core.settings.Settings` and one :class:`~stablemofusion.core.result.MotionResult`: text to motion, timeline, edit, stream;
:class:`~.motion_pipeline.MotionPipeline` offers them all. docs/architecture.md."""
