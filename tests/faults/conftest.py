"""The fault suite uses the integration fixtures (simulated PLC processes, a small disk)."""

from tests.integration.conftest import sim_plc_factory, small_disk  # noqa: F401
