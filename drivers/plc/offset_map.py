"""Where a CNC/PLC keeps the tool-wear offset the gauge writes, and how the exchange goes.

The gauge writes value and sequence in one FC16 write; the CNC applies the offset and echoes
the sequence into its acknowledgement register. Addresses are configurable; the defaults are
those of the simulated PLC (``shaftgauge sim-plc``).

| address | words | what | written by |
|---|---|---|---|
| offset_address     | 2 | offset, int32, 0.1 um                  | gauge (FC16) |
| offset_address + 2 | 2 | offset sequence number, uint32         | gauge (same FC16) |
| ack_address        | 2 | sequence number last applied, uint32   | CNC |
| total_address      | 2 | wear offset in total, int32, 0.1 um    | CNC (the limit's truth) |

A job of several offset entries: offset number ``n``'s block (a tool's own entry: its T
number's) is the same at ``(n - 1) * tool_stride`` further (0: the CNC keeps one block, and
the offsets of a job of several entries are only proposed).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from drivers.plc.registers import WordOrder


@dataclass(frozen=True)
class PlcOffsetMap:
    """Register addresses (0-based) of the offset exchange on the CNC side."""

    offset_address: int = 100
    ack_address: int = 104
    total_address: int = 106
    unit_id: int = 1
    word_order: WordOrder = WordOrder.BIG
    tool_stride: int = 0
    """Registers from one offset number's block to the next (0: one block)."""

    def span(self) -> int:
        """Registers from the block's first to its last, inclusive."""
        starts = (self.offset_address, self.ack_address, self.total_address)
        return max(self.offset_address + 4, self.ack_address + 2, self.total_address + 2) \
            - min(starts)

    def for_offset(self, number: int) -> PlcOffsetMap:
        """The block of offset number ``number`` (a T number for a tool's own entry; 1 and
        below: this one, the first). With one block (``tool_stride`` 0) every number's is
        this one. ValueError when the blocks would overlap, or lie beyond the registers."""
        if number <= 1 or self.tool_stride == 0:
            return self
        if self.tool_stride < self.span():
            raise ValueError(f"plc.tool_stride {self.tool_stride} is shorter than a block "
                             f"({self.span()} registers): the entries' blocks would overlap")
        shift = (number - 1) * self.tool_stride
        if max(self.offset_address, self.ack_address, self.total_address) + shift > 65533:
            raise ValueError(f"offset {number}'s block would lie beyond register 65535")
        return replace(self, offset_address=self.offset_address + shift,
                       ack_address=self.ack_address + shift,
                       total_address=self.total_address + shift, tool_stride=0)
