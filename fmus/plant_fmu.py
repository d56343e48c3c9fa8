"""The plant FMU: vessel dynamics, thrusters, sensors and environment."""

from ..components.plant import PlantBlock
from ._slave import BlockSlave


class PlantSlave(BlockSlave):
    BLOCK = PlantBlock
