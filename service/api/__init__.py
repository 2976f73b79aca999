"""The HTTP API (FastAPI): ``create_app(gauge)`` builds it around a running ``Gauge``."""
