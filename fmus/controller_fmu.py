"""The controller FMU: DP / autopilot: generalised force from estimates and setpoints."""

from ..components.controller import ControllerBlock
from ._slave import BlockSlave


class ControllerSlave(BlockSlave):
    BLOCK = ControllerBlock
