"""The REST API (FastAPI): submit jobs and sweeps, poll them, read results."""
