"""One router per resource, all under ``/v1`` except the probes and metrics."""

from . import batch, health, jobs, maneuvers, rigs, score

__all__ = ["batch", "health", "jobs", "maneuvers", "rigs", "score"]
