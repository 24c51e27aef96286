"""HTTP job service of MoJu: FastAPI app, job records in Redis, storage, client.

This package is imported by the workers too (settings, states, storage, job records), so it
must stay light: FastAPI is imported only by :mod:`service.app` and :mod:`service.routes`.
"""
