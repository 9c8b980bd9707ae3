"""Task pipelines (diffusers style: one per task, each ``__call__`` a numbered script from checking inputs to
post-processing) around shared :class:`~.components.Components`, one :class:`~.settings.Settings` and one
:class:`~.result.MotionResult`: text to motion, timeline, edit. docs/architecture.md."""
