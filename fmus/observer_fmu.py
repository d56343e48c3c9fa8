"""The observer FMU: EKF: position, attitude, velocity and bias estimates from the plant's sensors."""

from ..components.observer import ObserverBlock
from ._slave import BlockSlave


class ObserverSlave(BlockSlave):
    BLOCK = ObserverBlock
