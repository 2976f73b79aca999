"""Where a CNC/PLC keeps the tool-wear offset the gauge writes, and how the exchange goes.

The gauge writes value and sequence in one FC16 write; the CNC applies the offset and echoes
the sequence into its acknowledgement register. Addresses are configurable; the defaults are
those of the simulated PLC (``shaftgauge sim-plc``).

| address | words | what | written by |
|---|---|---|---|
| offset_address     | 2 | offset, int32, 0.1 um                  | gauge (FC16) |
| offset_address + 2 | 2 | offset sequence number, uint32         | gauge (same FC16) |
| ack_address        | 2 | sequence number last applied, uint32   | CNC |
| total_address      | 2 | wear offset applied in total, int32, 0.1 um | CNC (for display) |
"""

from __future__ import annotations

from dataclasses import dataclass

from drivers.plc.registers import WordOrder


@dataclass(frozen=True)
class PlcOffsetMap:
    """Register addresses (0-based) of the offset exchange on the CNC side."""

    offset_address: int = 100
    ack_address: int = 104
    total_address: int = 106
    unit_id: int = 1
    word_order: WordOrder = WordOrder.BIG
