"""HTTP layer of the render service (FastAPI routers and their dependencies)."""
