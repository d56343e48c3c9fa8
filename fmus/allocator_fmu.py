"""The allocator FMU: thrust allocation: shaft speed commands from the generalised force."""

from ..components.allocation import AllocatorBlock
from ._slave import BlockSlave


class AllocatorSlave(BlockSlave):
    BLOCK = AllocatorBlock
