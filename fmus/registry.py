"""Which Block each FMU kind wraps: the single map the build, the master and the tests share."""

from ..components.allocation import AllocatorBlock
from ..components.block import Block
from ..components.controller import ControllerBlock
from ..components.observer import ObserverBlock
from ..components.plant import PlantBlock

BLOCKS: dict[str, type[Block]] = {
    "plant": PlantBlock,
    "observer": ObserverBlock,
    "controller": ControllerBlock,
    "allocator": AllocatorBlock,
}
