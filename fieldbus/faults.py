"""Fault injection plan: which frame of which cycle is lost, late, corrupted or unanswered.

Deterministic in (config, seed, cycle): random faults are drawn per frame from a
generator seeded with ``(seed, 2, block)`` for blocks of cycles, so any cycle's faults
can be computed independently (both sides of a split network agree) and a fault-free
cycle costs one dictionary lookup.

Frame index within a cycle: 0 = SoC, n = PReq to node n, N + n = PRes of node n
(one PRes frame carries TPDO1 and TPDO2). Kinds: 'loss', 'late', 'corrupt',
'silent' (the node sends no PRes; from ``silent_nodes``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from fieldbus.timing import BLOCK_CYCLES

if TYPE_CHECKING:
    from fieldbus.config import FieldbusConfig


@dataclass
class CycleFaults:
    """Faults of one cycle: ``kinds[frame_index] = 'loss' | 'late' | 'corrupt' | 'silent'``."""

    cycle: int
    kinds: dict[int, str] = field(default_factory=dict)

    def describe(self, nodes: int) -> list[tuple[str, int, str]]:
        """(frame, node, kind) triples, frame in 'soc', 'preq', 'pres'."""
        out = []
        for index, kind in sorted(self.kinds.items()):
            if index == 0:
                out.append(("soc", 0, kind))
            elif index <= nodes:
                out.append(("preq", index, kind))
            else:
                out.append(("pres", index - nodes, kind))
        return out


class FaultPlan:
    """Per-cycle fault lookup built from ``config.faults``."""

    def __init__(self, config: "FieldbusConfig") -> None:
        self.config = config
        self.nodes = config.nodes
        self.frames = 2 * config.nodes + 1
        f = config.faults
        self.enabled = bool(f.random_enabled or f.bursts or f.silent_nodes)
        self._block_index = -1
        self._block: dict[int, CycleFaults] = {}

    def for_cycle(self, cycle: int) -> CycleFaults | None:
        """Faults of ``cycle``, or None when every frame goes through untouched."""
        if not self.enabled:
            return None
        block = cycle // BLOCK_CYCLES
        if block != self._block_index:
            self._load_block(block)
        return self._block.get(cycle)

    def _entry(self, table: dict[int, CycleFaults], cycle: int) -> CycleFaults:
        entry = table.get(cycle)
        if entry is None:
            entry = table[cycle] = CycleFaults(cycle)
        return entry

    def _load_block(self, block: int) -> None:
        f = self.config.faults
        n = self.nodes
        first, last = block * BLOCK_CYCLES, (block + 1) * BLOCK_CYCLES
        table: dict[int, CycleFaults] = {}
        if f.random_enabled:
            rng = np.random.default_rng((self.config.seed, 2, block))
            draw = rng.random((BLOCK_CYCLES, self.frames))
            p_loss = f.loss_probability
            p_late = p_loss + f.late_probability
            p_corrupt = p_late + f.corrupt_probability
            rows, cols = np.nonzero(draw < p_corrupt)
            for row, col in zip(rows.tolist(), cols.tolist()):
                u = draw[row, col]
                kind = "loss" if u < p_loss else ("late" if u < p_late else "corrupt")
                self._entry(table, first + row).kinds[col] = kind
        for burst in f.bursts:
            start = max(first, burst.start_cycle)
            stop = min(last, burst.start_cycle + burst.cycles)
            if burst.frames == "soc":
                indices = [0]
            elif burst.frames == "preq":
                indices = [burst.node]
            elif burst.frames == "pres":
                indices = [n + burst.node]
            else:
                indices = [burst.node, n + burst.node]
            for cycle in range(start, stop):
                kinds = self._entry(table, cycle).kinds
                for index in indices:
                    kinds[index] = burst.kind
        for silent in f.silent_nodes:
            start = max(first, silent.from_cycle)
            stop = last if silent.until_cycle is None else min(last, silent.until_cycle)
            for cycle in range(start, stop):
                self._entry(table, cycle).kinds[n + silent.node] = "silent"
        self._block = table
        self._block_index = block
