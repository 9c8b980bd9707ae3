"""`smf serve`: an HTTP API over the pipeline with dynamic batching (FastAPI + uvicorn)."""

from .app import create_app
from .batcher import DynamicBatcher, Job, QueueFull

__all__ = ["DynamicBatcher", "Job", "QueueFull", "create_app"]
