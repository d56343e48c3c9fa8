"""The controller FMU: DP / autopilot: generalised force from estimates and setpoints."""

from components.controller import ControllerBlock
from fmus._slave import BlockSlave


class ControllerSlave(BlockSlave):
    BLOCK = ControllerBlock
