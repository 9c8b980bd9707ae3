"""`smf serve`: an HTTP API over the pipeline with dynamic batching (FastAPI + uvicorn)."""

from .app import create_app
from .batcher import DynamicBatcher
from .http_errors import ServeError
from .worker import Job, ProcessWorker, ServedModel, ThreadWorker, WorkerSpec

__all__ = ["DynamicBatcher", "Job", "ProcessWorker", "ServeError", "ServedModel", "ThreadWorker", "WorkerSpec", "create_app"]
