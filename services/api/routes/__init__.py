"""One APIRouter per resource: ``health``, ``demonstrations``, ``skills``, ``executions``."""
